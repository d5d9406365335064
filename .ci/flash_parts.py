#!/usr/bin/env python3
"""Print what each part of a firmware image costs in flash, with no binutils needed.

Code (.text) is attributed through the DWARF line table (the release profile keeps
`debug = 2`), so code inlined into a task counts for the source file it comes from: a part is
a directory of this repository (`src/console`), a dependency crate (`stm32f4xx-hal`), a
library of the toolchain (`core::fmt`, `compiler_builtins`) or `(no line info)` (assembly,
padding). Generic code of `core` (pointer, slice, integer helpers) inlined into a function
counts for the nearest other part of that function, the code that used it; `core`'s own
functions (formatting, panics) keep their `core::` part. Read-only data (.rodata) is attributed by symbol where it has one; the rest
(strings, constants, jump tables) is one row. The vector table and .data's load image are one
row each. The rows add up to the flash total of `.ci/elf_size.py`.

Usage: flash_parts.py [--files] [--symbols N] [--markdown] ELF
  --files      one row per source file instead of per directory or crate
  --symbols N  also list the N largest symbols in flash (functions after inlining)
  --markdown   print Markdown tables (for docs/RESULTS.md)"""
import re
import struct
import sys
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ next to the scripts
sys.path.insert(0, str(Path(__file__).resolve().parent))
from elf_size import c_string, demangle, section_headers  # noqa: E402

FLASH_SECTIONS = (".vector_table", ".text", ".rodata", ".data", ".gnu.sgstubs")


def uleb(data, at):
    value = shift = 0
    while True:
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, at


def sleb(data, at):
    value = shift = 0
    while True:
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            if byte & 0x40:
                value -= 1 << shift
            return value, at


def sections_by_name(path):
    data, hdrs, shstrndx = section_headers(path)
    names = hdrs[shstrndx][4]
    found = {}
    for name, typ, flags, addr, off, size, *_ in hdrs:
        found[c_string(data, names + name)] = (typ, flags, addr, off, size)
    return data, found


def v5_entries(data, at, strs, line_strs):
    """The directory or file entries of a DWARF 5 line table header: lists of (name, dir)."""
    count = data[at]
    at += 1
    formats = []
    for _ in range(count):
        content, at = uleb(data, at)
        form, at = uleb(data, at)
        formats.append((content, form))
    n, at = uleb(data, at)
    entries = []
    for _ in range(n):
        name, directory = "", 0
        for content, form in formats:
            if form == 0x08:  # DW_FORM_string
                end = data.index(b"\0", at)
                value, at = data[at:end].decode(errors="replace"), end + 1
            elif form in (0x0E, 0x1F):  # DW_FORM_strp, DW_FORM_line_strp
                (off,) = struct.unpack_from("<I", data, at)
                at += 4
                table = strs if form == 0x0E else line_strs
                value = table[off:table.index(b"\0", off)].decode(errors="replace")
            elif form == 0x0F:  # DW_FORM_udata
                value, at = uleb(data, at)
            elif form in (0x0B, 0x05, 0x06):  # data1, data2, data4
                size = {0x0B: 1, 0x05: 2, 0x06: 4}[form]
                value = int.from_bytes(data[at:at + size], "little")
                at += size
            elif form == 0x1E:  # DW_FORM_data16 (MD5)
                value, at = None, at + 16
            elif form == 0x09:  # DW_FORM_block
                size, at = uleb(data, at)
                value, at = None, at + size
            else:
                raise ValueError(f"DWARF 5 line table: form 0x{form:x} not supported")
            if content == 1:  # DW_LNCT_path
                name = value
            elif content == 2:  # DW_LNCT_directory_index
                directory = value
        entries.append((name, directory))
    return entries, at


# Sizes of the DWARF attribute forms that a compile unit's first DIE may use: a number of
# bytes, "uleb", "addr" or "string".
FORM_SIZES = {
    0x01: "addr", 0x05: 2, 0x06: 4, 0x07: 8, 0x08: "string", 0x0B: 1, 0x0C: 1, 0x0D: "uleb",
    0x0E: 4, 0x0F: "uleb", 0x10: 4, 0x11: 1, 0x12: 2, 0x13: 4, 0x14: 8, 0x15: "uleb",
    0x17: 4, 0x19: 0, 0x1A: "uleb", 0x1B: "uleb", 0x1C: 4, 0x1D: 4, 0x1E: 16, 0x1F: 4,
    0x20: 8, 0x21: 0, 0x22: "uleb", 0x23: "uleb", 0x25: 1, 0x26: 2, 0x27: 3, 0x28: 4,
    0x29: 1, 0x2A: 2, 0x2B: 3, 0x2C: 4,
}


def comp_dirs(data, found):
    """The compile directory of each compile unit, by the offset of its line table: the
    line tables name files relative to it."""
    def section(name):
        _, _, _, o, s = found.get(name, (0, 0, 0, 0, 0))
        return data[o:o + s]

    info, abbrev = section(".debug_info"), section(".debug_abbrev")
    strs, line_strs = section(".debug_str"), section(".debug_line_str")
    dirs = {}
    at = 0
    while at + 11 <= len(info):
        (length,) = struct.unpack_from("<I", info, at)
        end = at + 4 + length
        (version,) = struct.unpack_from("<H", info, at + 4)
        if version >= 5:
            addr_size = info[at + 7]
            (abbrev_off,) = struct.unpack_from("<I", info, at + 8)
            die = at + 12
        else:
            (abbrev_off,) = struct.unpack_from("<I", info, at + 6)
            addr_size = info[at + 10]
            die = at + 11
        code, die = uleb(info, die)
        # The abbreviation of `code`: skip the others.
        a = abbrev_off
        while True:
            c, a = uleb(abbrev, a)
            _tag, a = uleb(abbrev, a)
            a += 1  # children
            specs = []
            while True:
                attr, a = uleb(abbrev, a)
                form, a = uleb(abbrev, a)
                if form == 0x21:
                    _, a = sleb(abbrev, a)
                if attr == 0 and form == 0:
                    break
                specs.append((attr, form))
            if c == code or c == 0:
                break
        comp_dir = stmt_list = None
        for attr, form in specs:
            size = FORM_SIZES.get(form)
            if size is None:
                break
            value = None
            if size == "string":
                stop = info.index(b"\0", die)
                value, die = info[die:stop].decode(errors="replace"), stop + 1
            elif size == "uleb":
                value, die = uleb(info, die)
            else:
                size = addr_size if size == "addr" else size
                value = int.from_bytes(info[die:die + size], "little")
                die += size
            if form in (0x0E, 0x1F) and attr == 0x1B:
                table = strs if form == 0x0E else line_strs
                value = table[value:table.index(b"\0", value)].decode(errors="replace")
            if attr == 0x1B and isinstance(value, str):
                comp_dir = value
            elif attr == 0x10:
                stmt_list = value
        if comp_dir is not None and stmt_list is not None:
            dirs[stmt_list] = comp_dir
        at = end
    return dirs


def line_header(data, at, end, strs, line_strs, comp_dir):
    """The header of one line table: (version, its fields, file paths, program start)."""
    (version,) = struct.unpack_from("<H", data, at)
    at += 2
    if version >= 5:
        at += 2  # address_size, segment_selector_size
    (header_length,) = struct.unpack_from("<I", data, at)
    at += 4
    program = at + header_length
    min_inst = data[at]
    at += 1
    if version >= 4:
        at += 1  # maximum_operations_per_instruction
    at += 1  # default_is_stmt
    line_base = struct.unpack_from("<b", data, at)[0]
    line_range, opcode_base = data[at + 1], data[at + 2]
    at += 3
    std_lengths = list(data[at:at + opcode_base - 1])
    at += opcode_base - 1
    if version >= 5:
        dirs, at = v5_entries(data, at, strs, line_strs)
        files, at = v5_entries(data, at, strs, line_strs)
        dir_names = [joined(comp_dir, d) for d, _ in dirs]
        paths = [joined(dir_names[d], f) if d < len(dir_names) else f for f, d in files]
    else:
        dir_names = [comp_dir]
        while data[at]:
            end_name = data.index(b"\0", at)
            dir_names.append(joined(comp_dir, data[at:end_name].decode(errors="replace")))
            at = end_name + 1
        at += 1
        paths = [""]
        while data[at]:
            end_name = data.index(b"\0", at)
            name = data[at:end_name].decode(errors="replace")
            d, at = uleb(data, end_name + 1)
            _, at = uleb(data, at)  # modification time
            _, at = uleb(data, at)  # length
            paths.append(joined(dir_names[d], name) if d < len(dir_names) else name)
    fields = (min_inst, line_base, line_range, opcode_base, std_lengths)
    return version, fields, paths, program


def joined(directory, name):
    """`name` inside `directory` unless it is absolute."""
    if not directory or name.startswith("/"):
        return name
    return f"{directory.rstrip('/')}/{name}"


def line_rows(data, at, end, fields, paths):
    """(address, file path) of each row of a line program, sequences ending in (address, None)."""
    min_inst, line_base, line_range, opcode_base, std_lengths = fields
    address, file = 0, 1

    def row():
        return (address, paths[file] if file < len(paths) else "?")

    while at < end:
        op = data[at]
        at += 1
        if op >= opcode_base:
            adjusted = op - opcode_base
            address += (adjusted // line_range) * min_inst
            yield row()
        elif op == 0:  # extended
            length, at = uleb(data, at)
            sub, body = data[at], at + 1
            at += length
            if sub == 1:  # DW_LNE_end_sequence
                yield (address, None)
                address, file = 0, 1
            elif sub == 2:  # DW_LNE_set_address
                (address,) = struct.unpack_from("<I", data, body)
        elif op == 1:  # DW_LNS_copy
            yield row()
        elif op == 2:  # DW_LNS_advance_pc
            n, at = uleb(data, at)
            address += n * min_inst
        elif op == 3:  # DW_LNS_advance_line
            _, at = sleb(data, at)
        elif op == 4:  # DW_LNS_set_file
            file, at = uleb(data, at)
        elif op == 8:  # DW_LNS_const_add_pc
            address += ((255 - opcode_base) // line_range) * min_inst
        elif op == 9:  # DW_LNS_fixed_advance_pc
            (n,) = struct.unpack_from("<H", data, at)
            at += 2
            address += n
        else:  # operands of the other standard opcodes: ULEB128 each
            for _ in range(std_lengths[op - 1]):
                _, at = uleb(data, at)
    _ = line_base


def code_by_file(data, found):
    """Bytes of code per source path, from the line tables of `.debug_line`."""
    if ".debug_line" not in found:
        sys.exit("no .debug_line: build with debug info (the release profile keeps debug = 2)")
    _, _, _, off, size = found[".debug_line"]
    lines = data[off:off + size]

    def section(name):
        if name not in found:
            return b""
        _, _, _, o, s = found[name]
        return data[o:o + s]

    strs, line_strs = section(".debug_str"), section(".debug_line_str")
    dirs = comp_dirs(data, found)
    spans = []
    at = 0
    while at < len(lines):
        (length,) = struct.unpack_from("<I", lines, at)
        end = at + 4 + length
        header = line_header(lines, at + 4, end, strs, line_strs, dirs.get(at, ""))
        _, fields, paths, program = header
        rows = list(line_rows(lines, program, end, fields, paths))
        for (a, f), (b, _) in zip(rows, rows[1:]):
            if f is not None and b > a:
                spans.append((a, b, f))
        at = end
    return spans


def part_of(path, per_file):
    """The part a source path belongs to."""
    path = path.replace("\\", "/")
    m = re.search(r"(?:^|/)library/(core|alloc|std)/src/(.*)", path)
    if m:
        sub = m.group(2).split("/")
        return f"{m.group(1)}::{sub[0].removesuffix('.rs')}" if not per_file else f"{m.group(1)}/{m.group(2)}"
    m = re.search(r"/(compiler[-_]builtins)[-0-9.]*/(.*)", path)
    if m:
        return "compiler_builtins"
    m = re.search(r"/registry/src/[^/]+/([^/]+?)-\d[^/]*/(.*)", path)
    if m:
        return m.group(1) if not per_file else f"{m.group(1)}/{m.group(2)}"
    if path.startswith("/rustc/"):
        return "rust (other)"
    # This repository, wherever it was built: the path from its `src/` on.
    path = re.sub(r"^.*?/(?=src/)", "", path)
    if per_file:
        return path
    # This repository: a module, `src/console` or `src/decimal.rs`.
    m = re.match(r"(src/[^/]+)(/.*)?$", path)
    return m.group(1) if m else path


def flash_ranges(found):
    """(name, address, size) of the loadable sections that occupy flash."""
    return [
        (name, found[name][2], found[name][4])
        for name in FLASH_SECTIONS
        if name in found and found[name][1] & 0x2 and found[name][4]
    ]


def symbols_with_address(data, found):
    """(name, address, size) of each named symbol of the symbol table (Thumb bit cleared)."""
    if ".symtab" not in found:
        return
    _, _, _, off, size = found[".symtab"]
    _, _, _, names, _ = found[".strtab"]
    for at in range(off, off + size, 16):
        st_name, value, st_size = struct.unpack_from("<III", data, at)
        if st_name:
            yield c_string(data, names + st_name), value & ~1, st_size


def functions(data, found):
    """Sorted (start, end) address ranges of the function symbols (STT_FUNC)."""
    if ".symtab" not in found:
        return []
    _, _, _, off, size = found[".symtab"]
    ranges = []
    for at in range(off, off + size, 16):
        _, value, st_size, info = struct.unpack_from("<IIIB", data, at)
        if info & 0xF == 2 and st_size:
            ranges.append((value & ~1, (value & ~1) + st_size))
    return sorted(set(ranges))


def is_library(part):
    """Parts of the toolchain's libraries, whose code is mostly generic code inlined into its
    callers (pointer, slice, integer and option helpers)."""
    return part.startswith(("core::", "core/", "alloc::", "alloc/"))


def code_parts(data, found, per_file):
    """Bytes of .text per part, and the bytes no line table covers. Library code inlined
    into a function of another part counts for the nearest other part of that function (the
    caller that inlined it); a function of library code alone keeps its library part."""
    _, _, t_addr, _, t_size = found[".text"]
    spans = sorted(
        (max(a, t_addr), min(b, t_addr + t_size), part_of(f, per_file))
        for a, b, f in code_by_file(data, found)
        if min(b, t_addr + t_size) > max(a, t_addr)
    )
    owned = []
    funcs = functions(data, found)
    fi = 0
    i = 0
    while i < len(spans):
        # The spans of one function (or of a stretch outside any function symbol).
        while fi < len(funcs) and funcs[fi][1] <= spans[i][0]:
            fi += 1
        if fi < len(funcs) and funcs[fi][0] <= spans[i][0]:
            end = funcs[fi][1]
        else:
            end = funcs[fi][0] if fi < len(funcs) else t_addr + t_size
        j = i
        while j < len(spans) and spans[j][0] < end:
            j += 1
        group = spans[i:max(j, i + 1)]
        callers = [k for k, (_, _, part) in enumerate(group) if not is_library(part)]
        for k, (a, b, part) in enumerate(group):
            if is_library(part) and callers:
                part = group[min(callers, key=lambda c: abs(c - k))][2]
            owned.append((a, b, part))
        i = max(j, i + 1)
    covered = bytearray(t_size)
    parts = {}
    for a, b, part in owned:
        lo, hi = a - t_addr, b - t_addr
        new = hi - lo - sum(covered[lo:hi])
        covered[lo:hi] = b"\x01" * (hi - lo)
        parts[part] = parts.get(part, 0) + new
    return parts, t_size - sum(covered)


def rodata_parts(data, found):
    """Bytes of .rodata per crate of its named symbols, and the unnamed rest."""
    if ".rodata" not in found:
        return {}, 0
    _, _, r_addr, _, r_size = found[".rodata"]
    parts, named = {}, 0
    for name, value, size in symbols_with_address(data, found):
        if size and r_addr <= value < r_addr + r_size and not name.startswith(".L"):
            path = demangle(name).lstrip("<")
            crate = path.split("::")[0] if "::" in path else "other"
            parts["rodata: " + crate] = parts.get("rodata: " + crate, 0) + size
            named += size
    return parts, r_size - named


def measure(path, per_file):
    """(rows of (part, bytes), flash total)."""
    data, found = sections_by_name(path)
    parts, uncovered = code_parts(data, found, per_file)
    parts["(no line info: assembly, padding)"] = uncovered
    rodata, rest = rodata_parts(data, found)
    parts.update(rodata)
    parts["rodata: strings, constants, jump tables"] = rest
    for name, _, size in flash_ranges(found):
        if name not in (".text", ".rodata"):
            parts[name + (" (load image)" if name == ".data" else "")] = size
    total = sum(size for _, _, size in flash_ranges(found))
    assert sum(parts.values()) == total, (sum(parts.values()), total)
    return sorted(((p, n) for p, n in parts.items() if n), key=lambda p: -p[1]), total


def largest_symbols(path, n):
    """The `n` largest symbols in flash, demangled, with their sizes."""
    data, found = sections_by_name(path)
    ranges = flash_ranges(found)
    seen = {}
    for name, value, size in symbols_with_address(data, found):
        in_flash = any(a <= value < a + s for _, a, s in ranges)
        if size and in_flash and not name.startswith(".L"):
            seen[name] = size
    return [(demangle(name), size) for name, size in sorted(seen.items(), key=lambda s: -s[1])[:n]]


def main():
    args = sys.argv[1:]
    per_file = "--files" in args
    markdown = "--markdown" in args
    args = [a for a in args if a not in ("--files", "--markdown")]
    n_symbols = 0
    if "--symbols" in args:
        i = args.index("--symbols")
        n_symbols = int(args[i + 1])
        del args[i:i + 2]
    if len(args) != 1 or args[0].startswith("-"):
        sys.exit(__doc__.split("\n\n")[-1])
    path = args[0]
    rows, total = measure(path, per_file)
    if markdown:
        print("| part | bytes | share |\n| --- | ---: | ---: |")
        for part, size in rows:
            print(f"| {part} | {size:,} | {100 * size / total:.1f} % |")
        print(f"| **flash total** | **{total:,}** | |")
    else:
        print(f"{'part':<48}{'bytes':>8}{'share':>8}")
        for part, size in rows:
            print(f"{part:<48}{size:>8}{100 * size / total:>7.1f}%")
        print(f"{'flash total':<48}{total:>8}")
    if n_symbols:
        symbols = largest_symbols(path, n_symbols)
        if markdown:
            print("\n| largest symbols (after inlining) | bytes |\n| --- | ---: |")
            for name, size in symbols:
                print(f"| `{name}` | {size:,} |")
        else:
            print(f"\n{'largest symbols (after inlining)':<72}{'bytes':>8}")
            for name, size in symbols:
                print(f"{name[:72]:<72}{size:>8}")


if __name__ == "__main__":
    try:
        main()
    except BrokenPipeError:
        sys.exit(0)
