"""``McuBackend``: the tracker backend interface (``run``, ``set_params``, ``snapshot``,
``energies``, ``mean_energy``, ``last_t``, ``counters``) over the microcontroller ELF in
the emulator, so ``Tracker(model, backend="mcu")`` and ``springtrack track --backend mcu``
run the very firmware image.  Results equal ``backend="fixed"`` bit for bit: the same C
source, and the host converts the integer rows to float64 as ``fixed/kernel.pyx`` does.
"""
from __future__ import annotations

import numpy as np

from ..fixed import q as fixed_q
from ..events import EVENT_DTYPE
from ..instances import TRACKING, per_instance
from ..track import TRACK_DTYPE, TRACK_FIELDS
from ..wire import TELE_TRACKER
from . import emulator as E
from .build import Capacity, cached_build

DEFAULT_TARGET = "cortex-m4"
POS_UNIT = 1.0 / 4294967296.0        # Q.32 px (as fixed/kernel.pyx)
VEL_UNIT = fixed_q.VEL_UNIT          # Q.32 px/us as px/s (eq. M7)
ROW_TRACKER = 9                      # int64 words per tracker in a row (entry.c MCU_ROW_TRACKER)
COV_UNIT = 1.0 / 1099511627776.0     # Q.40 px^2
Q32_UNIT = 1.0 / 4294967296.0        # Q.32 (activity)
Q40_UNIT = 1.0 / 1099511627776.0     # Q.40 (energies)
TELE_RECORD = TELE_TRACKER.itemsize    # bytes per tracker record
COUNTERS = ("events_valid", "events_assigned", "skipped_back_in_time", "skipped_outside_sensor",
            "spring_updates", "index_updates", "saturated_position", "saturated_activity",
            "saturated_energy", "saturated_inverse")


class McuBackend:
    """The fixed-point kernel as built for ``target``, run in the emulator."""

    native_records = True        # its sample rows carry the TELEMETRY records it packs

    def __init__(self, model, params, target: str = DEFAULT_TARGET, count: bool = False,
                 capacity: Capacity | None = None):
        """``capacity``: what the ELF is built for (default: exactly this model); builds
        are cached per source and capacity (build.cached_build)."""
        self.model = model
        self.build = cached_build(target, capacity or Capacity.of_model(model))
        self.emu = E.Emulator(self.build, count=count)
        self.n, self.nc = len(model.trackers), len(model.connections)
        self._load("mcu_words", fixed_q.model_words(model.arrays(), model.width, model.height),
                   E.MCU_LOAD_MODEL, "model")
        self.set_params(params)

    def _load(self, buf, words, cmd, what, inst: int = 0):
        self.emu.write(buf, words)
        st = self.emu.call(cmd, nwords=len(words), inst=inst)["status"]
        if st != 0:
            raise ValueError(f"mcu backend: the {what} does not load (status {st})")

    def set_params(self, params) -> None:
        self._load("mcu_words", fixed_q.params_words(params, self.nc), E.MCU_SET_PARAMS,
                   "parameters")

    def move(self, sim, model) -> None:
        """The instance moved rigidly by ``sim`` onto ``model`` (FixedKernel.move: fx_move
        in the firmware, the same words)."""
        words = fixed_q.move_words(sim, model, self.n, self.nc)
        self.emu.write("mcu_words", words)
        st = self.emu.call(E.MCU_MOVE, nwords=len(words))["status"]
        if st != 0:
            raise ValueError(f"mcu backend: the move does not load (fx_move {st}): the model "
                             f"must be the instance's own, moved")
        self.model = model

    def relocate(self, idx, x, y, sxx, sxy, syy) -> None:
        """Trackers ``idx`` put elsewhere (FixedKernel.relocate: fx_relocate in the
        firmware, the same words)."""
        self._relocate(self.emu, 0, idx, x, y, sxx, sxy, syy)

    @staticmethod
    def _relocate(emu, inst, idx, x, y, sxx, sxy, syy) -> None:
        words = fixed_q.relocate_words(idx, x, y, sxx, sxy, syy)
        emu.write("mcu_words", words)
        st = emu.call(E.MCU_RELOCATE, nwords=len(words), inst=inst)["status"]
        if st != 0:
            raise ValueError(f"mcu backend: the relocation does not load (fx_relocate {st})")

    # ---- events -------------------------------------------------------------------------
    def run(self, events, sample_us, next_t, cap, into=None):
        """As ``FixedKernel.run``: (consumed, next_t, samples) with at most ``cap`` rows;
        ``into`` is not used (the rows are read back from the emulated device)."""
        ev = np.ascontiguousarray(events)
        if ev.dtype.itemsize != 16:
            raise TypeError("events must be a C-contiguous EVENT_DTYPE array")
        per = self.emu.layout["events"]
        rows, wires, k, n, got = [], [], 0, len(ev), 0
        cap = cap if sample_us > 0 else 0
        while k < n:
            batch = ev[k:k + per]
            self.emu.write("mcu_events", batch)
            io = self.emu.call(E.MCU_RUN, nevents=len(batch), sample_us=int(sample_us),
                               next_t=int(next_t), cap=max(cap - got, 0))
            if io["status"] != 0:
                raise ValueError(f"mcu backend: sample period {sample_us} us is beyond the "
                                 f"firmware's 32-bit range")
            next_t = io["next_t"]
            if io["rows"]:
                r, w = self._rows(io["rows"])
                rows.append(r)
                wires.append(w)
                got += io["rows"]
            k += io["consumed"]
            if io["consumed"] < len(batch) and got >= cap:     # the rows are full
                break
        if sample_us <= 0:
            return n, next_t, None
        if not rows:
            rows = [np.empty((0, self.emu.layout["row_words"]), np.int64)]
            wires = [np.empty((0, self.n * TELE_RECORD), np.uint8)]
        return k, next_t, self._pack(np.concatenate(rows), np.concatenate(wires))

    def _rows(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """The first ``count`` integer rows (entry.c) and their TELEMETRY records."""
        w = self.emu.layout["row_words"]
        rows = self.emu.read_array("mcu_rows", np.int64, count * w).reshape(count, w)
        per = max(self.emu.layout["trackers"], self.emu.layout["set_trackers"]) * TELE_RECORD
        wire = self.emu.read_array("mcu_wire", np.uint8, count * per).reshape(count, per)
        return rows, wire[:, :self.n * TELE_RECORD]

    def _pack(self, rows: np.ndarray, wire: np.ndarray) -> dict:
        """Integer rows (entry.c) to the sample dict of springtrack.backends.samples (``t``,
        ``trackers`` of TRACK_DTYPE, ``energy``), converted as fixed/kernel.pyx's snapshot_row
        converts its state; ``wire``: the rows' TELEMETRY records, packed by the firmware."""
        n = self.n
        per = rows[:, 4:4 + ROW_TRACKER * n].reshape(len(rows), n, ROW_TRACKER)
        tr = np.empty((len(rows), n), TRACK_DTYPE)
        tr["x"] = per[:, :, 0].astype(np.float64) * POS_UNIT
        tr["y"] = per[:, :, 1].astype(np.float64) * POS_UNIT
        tr["sxx"] = per[:, :, 2].astype(np.float64) * COV_UNIT
        tr["sxy"] = per[:, :, 3].astype(np.float64) * COV_UNIT
        tr["syy"] = per[:, :, 4].astype(np.float64) * COV_UNIT
        tr["activity"] = per[:, :, 5].astype(np.float64) * Q32_UNIT
        tr["vx"] = per[:, :, 7].astype(np.float64) * VEL_UNIT     # eq. (M7), px/s
        tr["vy"] = per[:, :, 8].astype(np.float64) * VEL_UNIT
        tr["active"] = (per[:, :, 6] & 1).astype(bool)
        tr["sensitive"] = ((per[:, :, 6] >> 1) & 1).astype(bool)
        tr["state"] = per[:, :, 6] >> 2
        energy = (rows[:, 1:4].astype(np.float64) * Q40_UNIT / self.nc if self.nc
                  else np.zeros((len(rows), 3)))
        return {"t": rows[:, 0].copy(), "trackers": tr, "energy": energy, "wire": wire}

    def telemetry_records(self, t: int) -> bytes:
        """The TELEMETRY tracker records at event time t, packed by the firmware."""
        self.emu.call(E.MCU_SNAPSHOT, t=int(t))
        return self._rows(1)[1][0].tobytes()

    def step(self, t: int, x: int, y: int, p: int = 1) -> int:
        """One event of polarity p (1 ON, 0 OFF)."""
        ev = np.zeros(1, EVENT_DTYPE)
        ev[0] = (t, x, y, p)
        self.emu.write("mcu_events", ev)
        return self.emu.call(E.MCU_STEP)["status"]

    # ---- observation --------------------------------------------------------------------
    def snapshot(self, t: int) -> dict:
        self.emu.call(E.MCU_SNAPSHOT, t=int(t))
        tr = self._pack(*self._rows(1))["trackers"][0]
        return {f: tr[f].copy() for f in TRACK_FIELDS}

    def energies(self) -> np.ndarray:
        return self._energies(0, self.nc)

    def _energies(self, inst: int, nc: int) -> np.ndarray:
        self.emu.call(E.MCU_ENERGIES, inst=inst)
        c = self.emu.layout["connections"]
        e = self.emu.read_array("mcu_energy", np.int64, 3 * c).reshape(3, c)[:, :nc]
        return e.astype(np.float64) * Q40_UNIT

    def _counters(self) -> np.ndarray:
        return self.emu.read_array("mcu_counters", np.int64)

    @property
    def mean_energy(self) -> float:
        return float(self._counters()[11]) * Q40_UNIT

    @property
    def last_t(self) -> int:
        return int(self._counters()[10])

    def counters(self) -> dict:
        c = self._counters()
        return dict(zip(COUNTERS, (int(v) for v in c[:len(COUNTERS)])), state_resets=int(c[13]))


class McuSet(McuBackend):
    """Several model instances (springtrack.instances) in the firmware: one fx_state per
    instance and one event assignment (entry.c MCU_SET_INIT, fixed/csrc/fixed_step.c fx_set),
    bit for bit springtrack.fixed.kernel.FixedSet; its backend and instances' interface."""

    movable = True

    def __init__(self, mset, target: str = DEFAULT_TARGET, count: bool = False,
                 capacity: Capacity | None = None):
        self.mset = mset
        self.model = mset[0].model
        self.build = cached_build(target, capacity or Capacity.of_model(mset))
        self.emu = E.Emulator(self.build, count=count)
        self.n, self.nc = mset.n, mset.nc
        for q in range(len(mset)):
            self._load_instance(q)
        self._load("mcu_words", np.array([len(mset)], np.int32), E.MCU_SET_INIT, "set")
        self._states = [int(TRACKING)] * len(mset)

    def _load_instance(self, q: int) -> None:
        m = self.mset[q].model
        self._load("mcu_words", fixed_q.model_words(m.arrays(), m.width, m.height),
                   E.MCU_LOAD_MODEL, f"model of instance {self.mset[q].label}", inst=q)
        self._load("mcu_words", fixed_q.params_words(self.mset[q].params, len(m.connections)),
                   E.MCU_SET_PARAMS, "parameters", inst=q)

    def set_params(self, params) -> None:
        """One Params for every instance, or one per instance (the shared ones equal)."""
        self.mset = self.mset.with_params(per_instance(params, len(self.mset)))
        for q, inst in enumerate(self.mset):
            self._load("mcu_words", fixed_q.params_words(inst.params, inst.nc),
                       E.MCU_SET_PARAMS, "parameters", inst=q)

    def states(self) -> list:
        return list(self._states)

    def set_state(self, g: int, state) -> None:
        self.emu.write("mcu_words", np.array([int(state)], np.int32))
        self.emu.call(E.MCU_SET_STATE, inst=g)
        self._states[g] = int(state)

    def place(self, g: int, model) -> None:
        """Instance g loaded again as ``model`` (FixedSet.place), tracking."""
        self.mset = self.mset.replaced(g, model)
        self._load_instance(g)
        self._states[g] = int(TRACKING)

    def relocate(self, g: int, idx, x, y, sxx, sxy, syy) -> None:
        """Instance g's trackers ``idx`` put elsewhere (fx_relocate in the firmware)."""
        McuBackend._relocate(self.emu, g, idx, x, y, sxx, sxy, syy)

    def move(self, g: int, sim, model) -> None:
        inst = self.mset[g]
        words = fixed_q.move_words(sim, model, inst.n, inst.nc)
        self.emu.write("mcu_words", words)
        st = self.emu.call(E.MCU_MOVE, nwords=len(words), inst=g)["status"]
        if st != 0:
            raise ValueError(f"mcu backend: the move does not load (fx_move {st}): the model "
                             f"must be the instance's own, moved")
        self.mset = self.mset.replaced(g, model)

    def energies(self) -> np.ndarray:
        return np.concatenate([self._energies(q, inst.nc) for q, inst in enumerate(self.mset)],
                              axis=1)

    def mean_energies(self) -> list:
        v = self.emu.read_array("mcu_means", np.int64)[:len(self.mset)]
        return [float(x) * Q40_UNIT for x in v]

    def frame(self, g: int = 0) -> tuple:
        c, sn, gx, gy = (int(v) for v in self.emu.read_array("mcu_frames", np.int64)
                         .reshape(-1, 4)[g])
        return (c / 268435456.0, sn / 268435456.0, gx * POS_UNIT, gy * POS_UNIT)
