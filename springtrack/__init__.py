"""springtrack: real-time part-based shape tracking for event cameras.

Valeiras et al. 2015, "Asynchronous Neuromorphic Event-Driven Visual Part-Based
Shape Tracking" (IEEE TNNLS 26(12)).  See docs/algorithm.md.
"""
from .events import EVENT_DTYPE
from .model import ShapeModel, ModelError, load_model
from .params import Params, ParamError

__version__ = "0.1.0"

__all__ = ["EVENT_DTYPE", "ShapeModel", "ModelError", "load_model", "Params", "ParamError",
           "Tracker", "__version__"]


def __getattr__(name):
    if name == "Tracker":
        from .tracker import Tracker
        return Tracker
    raise AttributeError(name)
