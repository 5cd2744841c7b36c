"""Test helper: what a microcontroller ELF holds (symbols, instruction mnemonics), for the
checks that it needs no runtime helper and has no FPU instruction."""
import re

# symbols a floating-point, 128-bit or 64-bit division need from a runtime (libgcc,
# compiler-rt, the ARM EABI): none may appear
RUNTIME = re.compile(r"^__(aeabi_|.*(sf|df|tf|ti|di)[0-9]?$|.*float|.*fix|.*extend|.*trunc)")


def symbols(elf):
    from elftools.elf.elffile import ELFFile
    with open(elf, "rb") as f:
        e = ELFFile(f)
        return [(s.name, s["st_info"]["type"], s["st_shndx"])
                for s in e.get_section_by_name(".symtab").iter_symbols() if s.name]


def text_mnemonics(res):
    import capstone as cs
    from elftools.elf.elffile import ELFFile
    with open(res.elf, "rb") as f:
        sec = ELFFile(f).get_section_by_name(".text")
        code, addr = sec.data(), sec["sh_addr"]
    if res.target.arch == "arm":
        d = cs.Cs(cs.CS_ARCH_ARM, cs.CS_MODE_THUMB | cs.CS_MODE_MCLASS)
    else:
        d = cs.Cs(cs.CS_ARCH_RISCV, cs.CS_MODE_RISCV32 | cs.CS_MODE_RISCVC)
    return {m for _, _, m, _ in d.disasm_lite(code, addr)}
