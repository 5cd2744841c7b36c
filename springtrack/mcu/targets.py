"""The cores ``springtrack mcu build --target`` knows: how clang (``python -m ziglang cc``)
targets each one and how unicorn emulates it.  A registry, looked up by name."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Target:
    name: str
    triple: str                 # clang -target
    cpu: str                    # clang -mcpu (zig's spelling)
    arch: str                   # "arm" (Thumb-2, M-profile) or "riscv32"
    isa: str                    # for reports
    uc_cpu: str                 # unicorn CPU model constant (unicorn.arm_const / riscv_const)
    flags: tuple = ()


TARGETS = {
    t.name: t for t in (
        Target("cortex-m4", "thumb-freestanding-eabi", "cortex_m4", "arm", "ARMv7E-M Thumb-2",
               "UC_CPU_ARM_CORTEX_M4"),
        Target("cortex-m7", "thumb-freestanding-eabi", "cortex_m7", "arm", "ARMv7E-M Thumb-2",
               "UC_CPU_ARM_CORTEX_M7"),
        Target("rv32imac", "riscv32-freestanding-none", "generic_rv32+m+a+c", "riscv32",
               "RV32IMAC", "UC_CPU_RISCV32_SIFIVE_E31", ("-mno-relax",)),
    )
}


def target(name: str) -> Target:
    try:
        return TARGETS[name]
    except KeyError:
        raise ValueError(f"unknown microcontroller target {name!r}; choose from "
                         f"{', '.join(TARGETS)}") from None
