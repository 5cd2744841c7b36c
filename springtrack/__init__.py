"""springtrack: real-time part-based shape tracking for event cameras.

Valeiras et al. 2015, "Asynchronous Neuromorphic Event-Driven Visual Part-Based
Shape Tracking" (IEEE TNNLS 26(12)).  See docs/algorithm.md.
"""
from .events import EVENT_DTYPE
from .model import ShapeModel, ModelError, load_model
from .params import Params, ParamError

__version__ = "0.1.0"

__all__ = ["EVENT_DTYPE", "ShapeModel", "ModelError", "load_model", "Params", "ParamError",
           "Tracker", "learn", "learn_model", "__version__"]

# the facade's heavier names, imported on first use: name -> (module, attribute)
_LAZY = {"Tracker": ("springtrack.tracker", "Tracker"),
         "learn": ("springtrack.learning", "learn"),
         "learn_model": ("springtrack.learning", "learn_model")}


def __getattr__(name):
    if name in _LAZY:
        import importlib
        mod, attr = _LAZY[name]
        return getattr(importlib.import_module(mod), attr)
    raise AttributeError(name)
