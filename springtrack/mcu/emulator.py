"""Run the microcontroller ELF (springtrack/mcu/build.py) in the ``unicorn`` CPU emulator.

    >>> emu = Emulator(build_result)                # doctest: +SKIP
    >>> emu.write("mcu_words", words); emu.call(MCU_LOAD_MODEL, nwords=len(words))

The ELF's sections are mapped at their addresses (flash 0x08000000, RAM 0x20000000), the
stack pointer set to ``__stack_top`` and the return address to ``mcu_halt``; ``call``
runs ``mcu_main`` until it returns there.  With ``count=True`` every basic block adds its
instruction count (disassembled once per block with ``capstone`` and cached) to
``instructions``, and to ``spring_instructions`` while ``fx_springs`` runs (from its entry
to its return address), so profiling costs one Python call per block, not per
instruction.
"""
from __future__ import annotations

import re
import struct

import numpy as np

from . import need

FLASH_BASE = 0x08000000
RAM_BASE = 0x20000000
PAGE = 0x1000
STACK_FILL = 0xA5

# mcu_main commands (entry.c)
MCU_NOP, MCU_LOAD_MODEL, MCU_SET_PARAMS, MCU_RUN, MCU_STEP, MCU_SNAPSHOT, MCU_ENERGIES, \
    MCU_SPRINGS, MCU_MOVE, MCU_SET_INIT, MCU_SET_STATE, MCU_RELOCATE = range(12)
# mcu_io_t (entry.c): int64 sample_us, next_t, t; int32 cmd, status, nwords, nevents, cap,
# consumed, rows, inst
IO = struct.Struct("<qqqiiiiiiii")
IO_FIELDS = ("sample_us", "next_t", "t", "cmd", "status", "nwords", "nevents", "cap",
             "consumed", "rows", "inst")
# mcu_layout (entry.c)
LAYOUT_FIELDS = ("trackers", "connections", "events", "rows", "cells", "words", "row_words",
                 "counters", "instances", "set_trackers")


# loads (each may take a second cycle) and divisions (multi-cycle) in the mix
LOAD = re.compile(r"^(ldr|ldm|pop|lw|lh|lb|c\.lw|c\.lwsp)")
DIV = re.compile(r"^(udiv|sdiv|div|rem)")


def _round_up(v: int, a: int = PAGE) -> int:
    return (v + a - 1) // a * a


class Emulator:
    def __init__(self, build_result, count: bool = False):
        uc = need("unicorn")
        ELFFile = need("elftools.elf.elffile").ELFFile
        self.res = build_result
        tgt = build_result.target
        self.arm = tgt.arch == "arm"
        if self.arm:
            from unicorn import arm_const as C
            self.uc = uc.Uc(uc.UC_ARCH_ARM, uc.UC_MODE_THUMB | uc.UC_MODE_MCLASS)
            self.uc.ctl_set_cpu_model(getattr(C, tgt.uc_cpu))
            self.reg_sp, self.reg_ra, self.reg_pc = C.UC_ARM_REG_SP, C.UC_ARM_REG_LR, C.UC_ARM_REG_PC
        else:
            from unicorn import riscv_const as C
            self.uc = uc.Uc(uc.UC_ARCH_RISCV, uc.UC_MODE_RISCV32)
            self.uc.ctl_set_cpu_model(getattr(C, tgt.uc_cpu))
            self.reg_sp, self.reg_ra, self.reg_pc = (C.UC_RISCV_REG_SP, C.UC_RISCV_REG_RA,
                                                     C.UC_RISCV_REG_PC)
        self.sym = {}
        self._func_names = set()
        flash_end, ram_end, progbits = FLASH_BASE, RAM_BASE, []
        with open(build_result.elf, "rb") as f:
            e = ELFFile(f)
            for s in e.iter_sections():
                if not s["sh_flags"] & 2 or not s["sh_size"]:
                    continue
                a, n = s["sh_addr"], s["sh_size"]
                if a >= RAM_BASE:
                    ram_end = max(ram_end, a + n)
                else:
                    flash_end = max(flash_end, a + n)
                if s["sh_type"] == "SHT_PROGBITS":
                    progbits.append((a, s.data()))
            for s in e.get_section_by_name(".symtab").iter_symbols():
                if s.name:
                    self.sym[s.name] = (s["st_value"], s["st_size"])
                    if s["st_info"]["type"] == "STT_FUNC":
                        self._func_names.add(s.name)
        self.uc.mem_map(FLASH_BASE, _round_up(flash_end - FLASH_BASE))
        self.uc.mem_map(RAM_BASE, _round_up(ram_end - RAM_BASE))
        for a, data in progbits:
            self.uc.mem_write(a, data)
        self.layout = dict(zip(LAYOUT_FIELDS, self.read_array("mcu_layout", np.int32).tolist()))
        # a Thumb symbol's value has bit 0 set: the function spans [value & ~1, + size)
        self._funcs = sorted((a & ~1, (a & ~1) + size, name) for name, (a, size) in self.sym.items()
                             if size and FLASH_BASE <= a < RAM_BASE and name in self._func_names)
        self.main = self.addr("mcu_main")
        self.halt = self.addr("mcu_halt")
        self.stack = (self.sym["__stack_bottom"][0], self.sym["__stack_top"][0])
        self.uc.mem_write(self.stack[0], bytes([STACK_FILL]) * (self.stack[1] - self.stack[0]))
        self.instructions = 0
        self.spring_instructions = 0
        self.loads = self.divides = self.blocks = 0   # the mix, for a cycle estimate
        if count:
            self._count_setup()

    # ---- memory ---------------------------------------------------------------------
    def addr(self, name: str) -> int:
        return self.sym[name][0] & ~1             # Thumb functions have bit 0 set

    def write(self, name: str, data, offset: int = 0) -> None:
        buf = bytes(memoryview(np.ascontiguousarray(data)).cast("B")) if not isinstance(
            data, (bytes, bytearray)) else bytes(data)
        a, size = self.sym[name]
        if offset + len(buf) > size:
            raise ValueError(f"{len(buf)} bytes do not fit {name} ({size} bytes)")
        self.uc.mem_write(a + offset, buf)

    def read(self, name: str, nbytes: int | None = None, offset: int = 0) -> bytes:
        a, size = self.sym[name]
        return bytes(self.uc.mem_read(a + offset, size - offset if nbytes is None else nbytes))

    def read_array(self, name: str, dtype, count: int | None = None, offset: int = 0) -> np.ndarray:
        dt = np.dtype(dtype)
        raw = self.read(name, None if count is None else count * dt.itemsize, offset)
        return np.frombuffer(raw, dt).copy()

    def stack_used(self) -> int:
        """Bytes of the stack ever written (the watermark of the fill pattern)."""
        lo, hi = self.stack
        raw = bytes(self.uc.mem_read(lo, hi - lo))
        untouched = len(raw) - len(raw.lstrip(bytes([STACK_FILL])))
        return hi - lo - untouched

    # ---- calls ------------------------------------------------------------------------
    def call(self, cmd: int, **io) -> dict:
        """Run mcu_main with mcu_io.cmd = cmd and the given mcu_io fields; returns mcu_io."""
        cur = dict(zip(IO_FIELDS, IO.unpack(self.read("mcu_io", IO.size))))
        cur.update(io, cmd=cmd)
        self.write("mcu_io", IO.pack(*(cur[f] for f in IO_FIELDS)))
        self.uc.reg_write(self.reg_sp, self.stack[1])
        self.uc.reg_write(self.reg_ra, self.halt | (1 if self.arm else 0))
        try:
            self.uc.emu_start(self.main | (1 if self.arm else 0), self.halt)
        except need("unicorn").UcError as e:
            pc = self.uc.reg_read(self.reg_pc)
            raise RuntimeError(f"the {self.res.target.name} firmware faulted in command {cmd} "
                               f"at pc={pc:#x} ({self._function_of(pc & ~1)}): {e}") from None
        return dict(zip(IO_FIELDS, IO.unpack(self.read("mcu_io", IO.size))))

    # ---- instruction counting -----------------------------------------------------------
    def _count_setup(self):
        uc = need("unicorn")
        cs = need("capstone")
        if self.arm:
            self._cs = cs.Cs(cs.CS_ARCH_ARM, cs.CS_MODE_THUMB | cs.CS_MODE_MCLASS)
        else:
            self._cs = cs.Cs(cs.CS_ARCH_RISCV, cs.CS_MODE_RISCV32 | cs.CS_MODE_RISCVC)
        self._blocks: dict[tuple[int, int], tuple[int, str]] = {}
        self.by_function: dict[str, int] = {}
        self._springs = self.addr("fx_springs")
        self._spring_exit = None
        self.uc.hook_add(uc.UC_HOOK_BLOCK, self._on_block)

    def _function_of(self, address: int) -> str:
        for lo, hi, name in self._funcs:
            if lo <= address < hi:
                return name
        return "?"

    def _on_block(self, uc, address, size, _user):
        key = (address, size)
        hit = self._blocks.get(key)
        if hit is None:
            mn = [m for _, _, m, _ in self._cs.disasm_lite(bytes(uc.mem_read(address, size)),
                                                           address)]
            loads = sum(1 for m in mn if LOAD.match(m))
            divs = sum(1 for m in mn if DIV.match(m))
            hit = self._blocks[key] = (len(mn), self._function_of(address), loads, divs)
        n, fn, loads, divs = hit
        self.by_function[fn] = self.by_function.get(fn, 0) + n
        self.loads += loads
        self.divides += divs
        self.blocks += 1
        if address == self._springs and self._spring_exit is None:
            self._spring_exit = uc.reg_read(self.reg_ra) & ~1
        elif self._spring_exit is not None and address == self._spring_exit:
            self._spring_exit = None
        self.instructions += n
        if self._spring_exit is not None:
            self.spring_instructions += n
