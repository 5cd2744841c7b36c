"""The boards ``springtrack mcu build --board`` makes a bootable image for, as QEMU
(``qemu-system-arm``) models them: core, memory map, the host link's UART and where the
event stream lies.  A registry, looked up by name.

The event input is a DMA-style memory stream (docs/mcu.md, "The firmware image"): a
header and the sensor's words at ``stream_base``, which ``springtrack mcu run`` loads there
(QEMU's generic loader) and the firmware decodes as the camera interface's DMA would
deliver them.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Board:
    name: str                 # QEMU machine name (-M)
    target: str               # springtrack.mcu.targets core
    what: str                 # for reports
    flash: tuple[int, int]    # origin, bytes: code, constant tables, initialised data
    ram: tuple[int, int]      # origin, bytes: state, index, buffers, stack
    uart: str                 # UART driver (firmware/board.h): "stm32" or "cmsdk"
    uart_base: int            # the host link's UART (QEMU's serial0)
    stream: tuple[int, int]   # origin, bytes of the event stream region
    clock_hz: int             # the core clock the image runs at (UART baud divisor)
    # ns of QEMU's virtual clock per SysTick tick (its model's system clock): with -icount
    # shift=0 the instructions per tick, which `springtrack mcu profile --board` counts by;
    # 0: not known for this model
    qemu_tick_ns: int = 0

    def defines(self) -> list[str]:
        return [f"-DBOARD_UART_{self.uart.upper()}=1", f"-DLINK_UART=0x{self.uart_base:08x}u",
                f"-DSTREAM_BASE=0x{self.stream[0]:08x}u", f"-DSTREAM_BYTES={self.stream[1]}u",
                f"-DBOARD_CLOCK_HZ={self.clock_hz}u", f'-DBOARD_NAME="{self.name}"']


KiB = 1024
MiB = 1024 * KiB

BOARDS = {
    b.name: b for b in (
        # STM32F405RG: 1 MiB flash at 0x08000000 (aliased at 0, where the core fetches its
        # vector table), 128 KiB SRAM at 0x20000000 (the 64 KiB CCM is left unused); USART1
        # is serial0; the image runs on the reset clock (HSI, 16 MHz); the last 768 KiB of
        # flash hold the event stream (196,604 EVT 2.0 words)
        Board("netduinoplus2", "cortex-m4", "Netduino Plus 2 (STM32F405, Cortex-M4F)",
              (0x08000000, 256 * KiB), (0x20000000, 128 * KiB), "stm32", 0x40011000,
              (0x08040000, 768 * KiB), 16_000_000),
        # MPS2 AN386 / AN500: 4 MiB ZBT SSRAM1 at 0 (code), 4 MiB SSRAM2/3 at 0x20000000
        # (data), 16 MiB PSRAM (the event stream) at 0x21000000 (AN386) or 0x60000000
        # (AN500); CMSDK APB UART0 at 0x40004000 is serial0; 25 MHz system clock
        Board("mps2-an386", "cortex-m4", "Arm MPS2 AN386 (Cortex-M4)",
              (0x00000000, 4 * MiB), (0x20000000, 4 * MiB), "cmsdk", 0x40004000,
              (0x21000000, 16 * MiB), 25_000_000, 40),
        Board("mps2-an500", "cortex-m7", "Arm MPS2 AN500 (Cortex-M7)",
              (0x00000000, 4 * MiB), (0x20000000, 4 * MiB), "cmsdk", 0x40004000,
              (0x60000000, 16 * MiB), 25_000_000, 40),
    )
}


def board(name: str) -> Board:
    try:
        return BOARDS[name]
    except KeyError:
        raise ValueError(f"unknown board {name!r}; choose from {', '.join(BOARDS)}") from None
