"""One backend's spring update on a placed configuration (no events), and rigidly moved poses."""
from __future__ import annotations

import math
from . import probes
import springtrack


def pose(model, angle, scale, shift=(0.0, 0.0)):
    """The model's rest positions turned by ``angle`` rad and scaled by ``scale`` about its
    centre of mass G0, then shifted: the same shape, rigidly moved and scaled."""
    a = model.arrays()
    c, s = scale * math.cos(angle), scale * math.sin(angle)
    g0x, g0y = a["x"][0] - a["gdx0"][0], a["y"][0] - a["gdy0"][0]
    return (g0x + shift[0] + c * a["gdx0"] - s * a["gdy0"],
            g0y + shift[1] + s * a["gdx0"] + c * a["gdy0"])


class Springs:
    """One backend's spring update on a placed configuration (no events)."""

    def __init__(self, backend, model, params):
        self.backend, self.model = backend, model
        self.tr = springtrack.Tracker(model, params, backend=backend)

    def place(self, x, y):
        b = self.tr._b
        for i in range(len(x)):
            if self.backend == "reference":
                b.ref.mx[i], b.ref.my[i] = float(x[i]), float(y[i])
            elif self.backend == "cython":
                probes.load("kernel_probe").place(b, i, float(x[i]), float(y[i]))
            else:
                probes.load("fixed_probe").set_raw(b, i, x=int(round(x[i] * 2 ** 32)),
                                                   y=int(round(y[i] * 2 ** 32)))

    def update(self, x=None, y=None, times=1):
        """Place the trackers (if given) and run a spring update, ``times`` times over;
        return the positions after the last.  The Cartesian springs use the frame fitted
        at the update before, so a configuration placed anew settles that frame in a few
        updates."""
        for _ in range(times - 1):
            self.update(x, y)
        if x is not None:
            self.place(x, y)
        b = self.tr._b
        (b.ref if self.backend == "reference" else b).springs()
        st = self.tr.state(0)
        return st["x"], st["y"]
