"""The synthetic streams the kernel benchmarks share (kernel.py, fixed_speed.py, ab.py):
``springtrack.sim.synthetic.blob_stream`` of a preset, 300 k events/s of scene time."""

SCENES = {
    # preset: (noise fraction, motion)
    "face26": (0.62, dict(speed_px_s=(10, -5), rot_deg_s=-8, wobble_px=4)),
    "grid3x3": (0.62, dict(speed_px_s=(15, 8), rot_deg_s=10)),
}
