"""The simulated ATIS sensor and its scenes, with exact ground truth.

``scenes``: deterministic scenes of the paper's section IV (and test scenes);
``sensor``: the sensor model turning a scene into events (``simulate``);
``screen``: a second, independent generator (a 100 Hz screen, its own pixel model) with
the same outputs; ``generators``: both by name (``springtrack simulate --generator``).
The library's ``simulate`` and ``experiments`` commands and firmware_sim's simulated
camera both use them; nothing here knows a device or a host.
"""
