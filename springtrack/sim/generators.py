"""The scene generators by name: each turns a scene into ``(events, truth)`` chunks with
its own sensor assumptions, so a result can be checked on more than one.

``sensor``  springtrack.sim.sensor: Gaussian blobs and soft ellipses moving continuously,
            an ESIM/v2e-style contrast-threshold pixel (the project's simulator);
``screen``  springtrack.sim.screen: opaque anti-aliased shapes on a 100 Hz screen, optics
            blur, photoreceptor latency that grows in the dark, unequal ON/OFF
            thresholds, refractory bursts, readout jitter, shot noise, leak events.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class Generator:
    name: str
    simulate: Callable          # (scene, seconds, seed, chunk_us=, config=, stats=) -> chunks
    make_scene: Callable        # (name, seed, **params) -> scene
    scenes: dict                # name -> scene class
    config: Callable            # (noise_rate_hz, hot_pixels, **extra) -> config; None: default


def _given(**kw) -> dict:
    """The keywords whose value is not None (None: the config's default)."""
    return {k: v for k, v in kw.items() if v is not None}


def _sensor() -> Generator:
    from . import scenes, sensor
    return Generator("sensor", sensor.simulate, scenes.make_scene, scenes.SCENES,
                     lambda noise_rate_hz, hot_pixels, **kw: sensor.SensorConfig(**_given(
                         noise_rate_hz=noise_rate_hz, hot_pixels=hot_pixels, **kw)))


def _screen() -> Generator:
    from . import screen
    return Generator("screen", screen.simulate, screen.make_scene, screen.SCENES,
                     lambda noise_rate_hz, hot_pixels, **kw: screen.ScreenConfig(**_given(
                         leak_rate_hz=noise_rate_hz, hot_pixels=hot_pixels, **kw)))


GENERATORS = {"sensor": _sensor, "screen": _screen}
DEFAULT = "sensor"


def generator(name: str) -> Generator:
    """The generator called ``name``; unknown names raise ValueError naming the known ones."""
    if name not in GENERATORS:
        raise ValueError(f"unknown generator {name!r}; known: {', '.join(GENERATORS)}")
    return GENERATORS[name]()
