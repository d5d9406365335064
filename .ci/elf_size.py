#!/usr/bin/env python3
"""Print flash and static RAM use of an ARM ELF (like `size -A`), with no binutils needed,
and fail when a loadable section overlaps the settings sectors (memory.x)."""
import struct
import sys


def sections(path):
    data = open(path, "rb").read()
    if data[:4] != b"\x7fELF" or data[4] != 1:
        sys.exit(f"{path}: not a 32-bit ELF")
    (shoff,) = struct.unpack_from("<I", data, 0x20)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x2E)
    hdrs = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]
    strtab = hdrs[shstrndx]
    for name, typ, flags, addr, off, size, *_ in hdrs:
        end = data.index(b"\0", strtab[4] + name)
        yield data[strtab[4] + name:end].decode(), typ, flags, addr, size


# Flash sectors 1 and 2 of the STM32F401: the settings store (memory.x, src/board/flash.rs).
SETTINGS = (0x0800_4000, 0x0800_C000)


def main():
    path = sys.argv[1]
    flash = ram = 0
    overlaps = []
    print(f"{'section':<24}{'size':>10}  address")
    for name, typ, flags, addr, size in sections(path):
        if not flags & 0x2 or size == 0:  # SHF_ALLOC
            continue
        print(f"{name:<24}{size:>10}  0x{addr:08x}")
        if addr < SETTINGS[1] and addr + size > SETTINGS[0]:
            overlaps.append(name)
        if name in (".vector_table", ".text", ".rodata", ".data", ".gnu.sgstubs"):
            flash += size
        if name in (".data", ".bss", ".uninit"):
            ram += size
    print(f"flash: {flash} bytes ({flash / 1024:.1f} KiB); static RAM: {ram} bytes ({ram / 1024:.1f} KiB)")
    if overlaps:
        sys.exit(f"{path}: {', '.join(overlaps)} overlap the settings sectors 0x{SETTINGS[0]:08x}..0x{SETTINGS[1]:08x}")


if __name__ == "__main__":
    main()
