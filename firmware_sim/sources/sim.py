"""``sim:SCENE``: a scene of ``springtrack.sim`` through the simulated camera."""
from __future__ import annotations

from . import SourceOptions, profile, simulated

USAGE = "sim:SCENE"
HELP = ("a scene of springtrack.sim.scenes (face_occlusion, grid_pull, ...) through the "
        "simulated USB camera (the CCam ATIS, or an EVK in --profile's words); its own "
        "shape model unless one is given")


def scene_source(scene: str, seconds: float | None = None, seed: int = 0,
                 chunk_us: int = 2000, **scene_params):
    """Events of a ``springtrack.sim`` scene, chunk by chunk (generated lazily)."""
    from springtrack.sim.sensor import simulate
    for events, _truth in simulate(scene, seconds, seed=seed, chunk_us=chunk_us, **scene_params):
        yield events


def open(target: str, opts: SourceOptions, url: str):
    from springtrack.sim.scenes import HEIGHT, WIDTH, make_scene
    scene = make_scene(target, seed=opts.seed)        # unknown scene: ValueError now

    def events():
        return scene_source(target, opts.seconds, seed=opts.seed)
    return simulated(url, events(), opts, profile(opts.profile, WIDTH, HEIGHT), restart=events,
                     default_model=scene.initial_model)
