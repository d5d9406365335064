#!/usr/bin/env python3
"""Print flash and static RAM use of an ARM ELF (like `size -A`), with no binutils needed,
and fail when a loadable section overlaps the settings sectors (memory.x).

With `--no-float-formatting` also fail when the image links core's float formatting
(`core::fmt::float`, `flt2dec`: Grisu and Dragon): a `{:.0}` of an f64 costs about 13 KiB
of flash. The firmware writes numbers as integers or leaves formatting to the host (defmt).

Usage: elf_size.py [--no-float-formatting] ELF"""
import re
import struct
import sys


def section_headers(path):
    """The file's bytes and its section headers (Elf32_Shdr tuples)."""
    data = open(path, "rb").read()
    if data[:4] != b"\x7fELF" or data[4] != 1:
        sys.exit(f"{path}: not a 32-bit ELF")
    (shoff,) = struct.unpack_from("<I", data, 0x20)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x2E)
    hdrs = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]
    return data, hdrs, shstrndx


def c_string(data, at):
    return data[at:data.index(b"\0", at)].decode(errors="replace")


def sections(path):
    data, hdrs, shstrndx = section_headers(path)
    strtab = hdrs[shstrndx]
    for name, typ, flags, addr, off, size, *_ in hdrs:
        yield c_string(data, strtab[4] + name), typ, flags, addr, size


def symbols(path):
    """(name, size) of every symbol of the symbol table (mangled names)."""
    data, hdrs, _ = section_headers(path)
    for _name, typ, _flags, _addr, off, size, link, _info, _align, entsize in hdrs:
        if typ != 2:  # SHT_SYMTAB
            continue
        names = hdrs[link][4]
        for at in range(off, off + size, entsize or 16):
            st_name, _value, st_size = struct.unpack_from("<III", data, at)
            if st_name:
                yield c_string(data, names + st_name), st_size


# Core's float formatting: the module `core::fmt::float` (Display/Debug/LowerExp of f32 and
# f64) and what it calls, `core::num::flt2dec` with its Grisu and Dragon strategies. Found in
# legacy (`_ZN4core3fmt5float...`) and v0 (`...4core3fmt5float...`) mangled names.
FLOAT_FORMATTING = ("3fmt5float", "float_to_decimal", "float_to_exponential", "flt2dec", "grisu", "dragon")


def demangle(name):
    """Readable path of a Rust symbol, best effort: the identifiers of a legacy (`_ZN...E`,
    hash dropped) or v0 (`_R...`, crate hashes, generics and back-references dropped) name."""
    if name.startswith("_R"):
        body, parts, i = re.sub(r"(?<=[CNXY])s[0-9A-Za-z]*_", "", name[2:]), [], 0
        while i < len(body):
            n = re.match(r"[1-9]\d*", body[i:])
            if not n or (i and body[i - 1].isdigit()):
                i += 1
                continue
            j = i + n.end() + (body[i + n.end():i + n.end() + 1] == "_")
            ident = body[j:j + int(n.group())]
            if len(ident) == int(n.group()) and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", ident):
                parts.append(ident)
                i = j + len(ident)
            else:
                i += n.end()
        return "::".join(parts) or name
    m = re.fullmatch(r"_ZN((?:\d+.+?)+)E", name)
    if not m:
        return name
    rest, parts = m.group(1), []
    while rest:
        n = re.match(r"\d+", rest)
        if not n:
            return name
        k = int(n.group())
        parts.append(rest[n.end():n.end() + k])
        rest = rest[n.end() + k:]
    if re.fullmatch(r"h[0-9a-f]{16}", parts[-1]):
        parts.pop()
    path = "::".join(parts)
    for code, text in (("_$LT$", "<"), ("$LT$", "<"), ("$GT$", ">"), ("$u20$", " "), ("$RF$", "&"), ("..", "::")):
        path = path.replace(code, text)
    return path


def float_formatting(path):
    """The symbols of core's float formatting in the image, largest first, and their bytes."""
    found = {}
    for name, size in symbols(path):
        if any(p in name for p in FLOAT_FORMATTING):
            found[name] = max(size, found.get(name, 0))
    return sorted(found.items(), key=lambda s: -s[1])


# Flash sectors 1 and 2 of the STM32F401: the settings store (memory.x, src/board/flash.rs).
SETTINGS = (0x0800_4000, 0x0800_C000)


def main():
    args = sys.argv[1:]
    no_float = "--no-float-formatting" in args
    args = [a for a in args if a != "--no-float-formatting"]
    if len(args) != 1 or args[0].startswith("-"):
        sys.exit(__doc__.rsplit("\n", 1)[-1])
    path = args[0]
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
    if no_float:
        found = float_formatting(path)
        if found:
            listing = "\n".join(f"  {size:>6}  {demangle(name)}" for name, size in found)
            sys.exit(
                f"{path}: links core's float formatting ({sum(s for _, s in found)} bytes in these "
                f"symbols):\n{listing}\n"
                "A `{}`, `{:?}` or `{:.N}` of an f32/f64 in the firmware (a `write!`, a `format_args!`, "
                "a Display impl) pulls it in (about 13 KiB). Write the number as integers (as "
                "src/decimal.rs does) or log it with defmt, which formats on the host."
            )
        print("float formatting: none linked")


if __name__ == "__main__":
    main()
