#!/usr/bin/env python3
"""Generate storetrack/msg/messages.hpp and the docs/icd.md tables from common/msg/schema/*.yaml.

The schema is the ONE definition of the wire messages. This script turns it into
  * C++ (build time, into the build tree): plain structs, flag constants, per-field metadata,
    the 64-bit mark word packing/unpacking and the big-endian payload encoder/decoder with range
    checks (used by both the UDP and the CAN FD framing);
  * markdown tables for docs/icd.md, between
        <!-- BEGIN GENERATED schema:<name> -->  ...  <!-- END GENERATED schema:<name> -->
    markers. `--check-icd docs/icd.md` fails (exit 1, with a diff) when the document drifted,
    `--update-icd docs/icd.md` rewrites the generated blocks and keeps the prose.

Usage:
  generate.py --header OUT/storetrack/msg/messages.hpp
  generate.py --check-icd docs/icd.md
  generate.py --update-icd docs/icd.md
  generate.py --check-doc docs/fti-output.md   (another document: only the blocks it holds)
"""

import argparse
import difflib
import math
import os
import re
import sys

import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
SCHEMA_FILES = ["mark_observations.yaml", "unit_health.yaml", "fti_sample.yaml",
                "raw_observation.yaml", "recorded_input.yaml"]

# Scalar wire types: (C++ type, bytes, put_/get_ suffix of storetrack/bytes/byte_cursor.hpp).
SCALARS = {
    "u8": ("std::uint8_t", 1, "u8"),
    "u16": ("std::uint16_t", 2, "u16"),
    "u32": ("std::uint32_t", 4, "u32"),
    "u64": ("std::uint64_t", 8, "u64"),
    "i8": ("std::int8_t", 1, "i8"),
    "i16": ("std::int16_t", 2, "i16"),
    "i32": ("std::int32_t", 4, "i32"),
    "i64": ("std::int64_t", 8, "i64"),
    "f32": ("float", 4, "f32"),
    "f64": ("double", 8, "f64"),
}
CPP_OF_STRUCT_TYPE = {"float": "float", "double": "double", "u8": "std::uint8_t",
                      "u16": "std::uint16_t", "u32": "std::uint32_t"}


def fail(msg):
    sys.stderr.write("generate.py: error: %s\n" % msg)
    sys.exit(2)


def camel_to_snake(name):
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


def snake_to_camel(name):
    return "".join(p.capitalize() for p in name.split("_"))


def parse_type(t):
    m = re.fullmatch(r"(\w+)(?:\[(\d+)\])?", str(t))
    if not m or m.group(1) not in SCALARS:
        fail("unknown type %r" % t)
    return m.group(1), (int(m.group(2)) if m.group(2) else None)


def invalid_text(v):
    """The invalid value as the ICD shows it."""
    if isinstance(v, bool):
        fail("boolean invalid value")
    if isinstance(v, int):
        return "0x%X" % v if v > 9 else str(v)
    return str(v)


def invalid_cpp(v, scalar):
    cpp = SCALARS[scalar][0]
    if isinstance(v, int):
        return "%s{%s}" % (cpp, hex(v) if v > 9 else str(v))
    s = str(v)
    if s == "NaN":
        return "std::numeric_limits<%s>::quiet_NaN()" % cpp
    m = re.fullmatch(r"(U?INT\d+)_(MIN|MAX)", s)
    if m:
        return "std::numeric_limits<%s>::%s()" % (cpp, m.group(2).lower())
    fail("cannot express invalid value %r" % v)


def constant_cpp(s, f):
    """The C++ value of a field the schema fixes (`constant: version`: the message version, so a
    reader of a recording or stream refuses another layout by this field)."""
    if f["constant"] != "version":
        fail("%s.%s: unknown constant %r (only 'version')" % (s["message"], f["name"], f["constant"]))
    return "k%sVersion" % s["message"]


def member_fields(s):
    """The fields that are members of the C++ struct (not the constants the codec writes)."""
    return [f for f in s["fields"] if "constant" not in f]


def cstr(s):
    return '"' + str(s).replace("\\", "\\\\").replace('"', '\\"') + '"'


def load_schemas(schema_dir):
    schemas = []
    for f in SCHEMA_FILES:
        with open(os.path.join(schema_dir, f)) as fh:
            s = yaml.safe_load(fh)
        s["_file"] = f
        offset = 0
        for fld in s["fields"]:
            scalar, count = parse_type(fld["type"])
            fld["_scalar"], fld["_count"] = scalar, count
            fld["_size"] = SCALARS[scalar][1] * (count or 1)
            fld["_offset"] = offset
            offset += fld["_size"]
        s["_fixed_bytes"] = offset
        rep = s.get("repeated")
        if rep:
            total = sum(f["bits"] for f in rep["fields"])
            if total != rep["packed_bits"]:
                fail("%s: repeated bit widths sum to %d, not %d" % (f, total, rep["packed_bits"]))
            shift = rep["packed_bits"]
            for rf in rep["fields"]:
                shift -= rf["bits"]
                rf["_shift"] = shift
                rf["_mask"] = (1 << rf["bits"]) - 1
            s["_max_bytes"] = offset + rep["max_count"] * rep["packed_bits"] // 8
        elif s.get("tail"):
            # A byte string after the fixed fields, as long as the sum of its length fields.
            tail = s["tail"]
            names = [f["name"] for f in s["fields"]]
            for lf in tail["length_fields"]:
                if lf not in names:
                    fail("%s: tail length field %r is not a field" % (f, lf))
            s["_max_bytes"] = offset + tail["max_bytes"]
        else:
            s["_max_bytes"] = offset
        schemas.append(s)
    ids = [s["id"] for s in schemas]
    if len(set(ids)) != len(ids) or max(ids) > 0x7F:
        fail("message ids must be unique and fit 7 bits (CAN FD identifier FID field)")
    return schemas


# ------------------------------------------------------------------------------------------
# C++ generation
# ------------------------------------------------------------------------------------------
def gen_flag_namespace(lines, ns, bits, cpp_type, doc):
    lines.append("/// %s" % doc)
    lines.append("namespace %s {" % ns)
    for b in bits:
        lines.append("inline constexpr %s k%s = %s{1u << %d};  ///< %s" %
                     (cpp_type, snake_to_camel(b["name"]), cpp_type, b["bit"], b["doc"]))
    mask = sum(1 << b["bit"] for b in bits)
    lines.append("inline constexpr %s kAllKnown = %s{0x%X};  ///< every defined bit" %
                 (cpp_type, cpp_type, mask))
    lines.append("}  // namespace %s" % ns)
    lines.append("")


FLAG_NAMESPACES = {
    # (message, field) -> namespace name fixed by TEAM.md
    ("MarkObservation", "flags"): "mark_flags",
    ("MarkObservations", "flags"): "exposure_flags",
    ("UnitHealth", "status"): "unit_status",
    ("FtiSample", "status"): "fti_status",
    ("RawObservation", "flags"): "raw_observation_flags",
}


def gen_mark_codec(lines, s):
    rep = s["repeated"]
    st = rep["struct"]
    lines.append("// ---- %s: one %d-bit big-endian word, fields from the MSB down ----" %
                 (st, rep["packed_bits"]))
    lines.append("namespace %s_word {" % camel_to_snake(st))
    for rf in rep["fields"]:
        n = snake_to_camel(rf["name"])
        lines.append("inline constexpr unsigned k%sBits = %d;" % (n, rf["bits"]))
        lines.append("inline constexpr unsigned k%sShift = %d;" % (n, rf["_shift"]))
        lines.append("inline constexpr std::uint64_t k%sMask = 0x%X;" % (n, rf["_mask"]))
        lines.append("inline constexpr std::uint64_t k%sInvalidCode = 0x%X;" % (n, rf["invalid"]))
        if "scale" in rf and rf.get("encoding", "linear") == "linear":
            # The values of the lowest and highest valid codes (what pack_mark accepts, to within
            # half a step): callers check their ranges against these, not against a copy.
            inv = rf["invalid"]
            top = rf["_mask"] - 1 if inv == rf["_mask"] else rf["_mask"]
            bottom = 1 if inv == 0 else 0
            off, scale = float(rf.get("offset", 0.0)), float(rf["scale"])
            lines.append("inline constexpr double k%sMinValue = %r;" % (n, off + bottom * scale))
            lines.append("inline constexpr double k%sMaxValue = %r;" % (n, off + top * scale))
    widths = " + ".join("k%sBits" % snake_to_camel(rf["name"]) for rf in rep["fields"])
    lines.append("static_assert(%s == %d, \"mark word bit widths must fill the word\");" %
                 (widths, rep["packed_bits"]))
    lines.append("}  // namespace %s_word" % camel_to_snake(st))
    lines.append("")
    lines.append("/// Packs one mark into its wire word. Returns false (word untouched) when a field"
                 " whose\n/// schema says `overflow: reject` is not representable (NaN or outside"
                 " its range);\n/// `overflow: saturate` fields are clamped to their largest code.")
    lines.append("inline bool pack_mark(const %s& m, std::uint64_t& word) {" % st)
    lines.append("  std::uint64_t w = 0;")
    ns = camel_to_snake(st) + "_word"
    for rf in rep["fields"]:
        n = snake_to_camel(rf["name"])
        name = rf["name"]
        enc = rf.get("encoding", "linear" if "scale" in rf else "raw")
        ov = rf.get("overflow", "saturate")
        lines.append("  {  // %s" % name)
        if rf.get("flag_bits") is not None or enc == "raw":
            lines.append("    const std::uint64_t code = static_cast<std::uint64_t>(m.%s) & %s::k%sMask;"
                         % (name, ns, n))
        elif enc == "log2":
            base, step = rf["log_base"], rf["log_step"]
            lines.append("    std::uint64_t code = %s::k%sInvalidCode;" % (ns, n))
            lines.append("    const double v = static_cast<double>(m.%s);" % name)
            lines.append("    if (v > 0.0 && std::isfinite(v)) {  // NaN, <= 0, inf: invalid code")
            lines.append("      const double t = std::log2(v / %r) / %r;" % (base, step))
            lines.append("      const double max_code = static_cast<double>(%s::k%sInvalidCode - 1);"
                         % (ns, n))
            if ov == "reject":
                lines.append("      if (t < -0.5 || t >= max_code + 0.5) return false;")
            lines.append("      code = static_cast<std::uint64_t>(std::lround(std::clamp(t, 0.0, max_code)));")
            lines.append("    }")
        elif enc == "linear":
            scale, off = rf["scale"], rf.get("offset", 0.0)
            inv = rf["invalid"]
            top = rf["_mask"] - 1 if inv == rf["_mask"] else rf["_mask"]
            bottom = 1 if inv == 0 else 0
            lines.append("    const double v = static_cast<double>(m.%s);" % name)
            lines.append("    const double t = (v - (%r)) / %r;" % (float(off), float(scale)))
            if ov == "reject":
                lines.append("    if (!(t >= %d - 0.5 && t < %d + 0.5)) return false;  // NaN too" %
                             (bottom, top))
                lines.append("    const std::uint64_t code = static_cast<std::uint64_t>(std::floor(t + 0.5));")
            else:
                if inv == 0:
                    lines.append("    std::uint64_t code = 0;  // invalid (unknown) for NaN and <= 0")
                    lines.append("    if (t > 0.0) code = static_cast<std::uint64_t>(std::floor(std::clamp(t, %d.0, %d.0) + 0.5));"
                                 % (bottom, top))
                else:
                    lines.append("    std::uint64_t code = %s::k%sInvalidCode;" % (ns, n))
                    lines.append("    if (!std::isnan(t)) code = static_cast<std::uint64_t>(std::floor(std::clamp(t, %d.0, %d.0) + 0.5));"
                                 % (bottom, top))
        else:
            fail("unknown encoding %r" % enc)
        lines.append("    w |= code << %s::k%sShift;" % (ns, n))
        lines.append("  }")
    lines.append("  word = w;")
    lines.append("  return true;")
    lines.append("}")
    lines.append("")
    lines.append("/// Unpacks one wire word. Returns false when a field whose schema says"
                 " `overflow: reject`\n/// carries its invalid code (a mark without a position is"
                 " malformed).")
    lines.append("inline bool unpack_mark(std::uint64_t word, %s& m) {" % st)
    for rf in rep["fields"]:
        n = snake_to_camel(rf["name"])
        name = rf["name"]
        enc = rf.get("encoding", "linear" if "scale" in rf else "raw")
        ctype = CPP_OF_STRUCT_TYPE[rf["type"]]
        lines.append("  {  // %s" % name)
        lines.append("    const std::uint64_t code = (word >> %s::k%sShift) & %s::k%sMask;" %
                     (ns, n, ns, n))
        if rf.get("overflow") == "reject":
            lines.append("    if (code == %s::k%sInvalidCode) return false;" % (ns, n))
        if rf.get("flag_bits") is not None or enc == "raw":
            lines.append("    m.%s = static_cast<%s>(code);" % (name, ctype))
        elif enc == "log2":
            lines.append("    m.%s = code == %s::k%sInvalidCode ? std::numeric_limits<%s>::quiet_NaN()"
                         % (name, ns, n, ctype))
            lines.append("           : static_cast<%s>(%r * std::exp2(static_cast<double>(code) * %r));"
                         % (ctype, rf["log_base"], rf["log_step"]))
        else:
            off = float(rf.get("offset", 0.0))
            lines.append("    m.%s = static_cast<%s>(static_cast<double>(code) * %r + (%r));" %
                         (name, ctype, float(rf["scale"]), off))
        lines.append("  }")
    lines.append("  return true;")
    lines.append("}")
    lines.append("")


def gen_field_info(lines, s):
    msg = s["message"]
    lines.append("inline constexpr std::array<FieldInfo, %d> k%sFields{{" % (len(s["fields"]), msg))
    for f in s["fields"]:
        lines.append("    {%s, %s, %s, %s, %s, %s, %d, %d}," % (
            cstr(f["name"]), cstr(f["type"]), cstr(f["unit"]), cstr(f["frame"]),
            cstr(invalid_text(f["invalid"])), cstr(f["doc"]), f["_offset"], f["_size"]))
    lines.append("}};")
    rep = s.get("repeated")
    if rep:
        lines.append("inline constexpr std::array<BitFieldInfo, %d> k%sWordFields{{" %
                     (len(rep["fields"]), rep["struct"]))
        for rf in rep["fields"]:
            lines.append("    {%s, %s, %s, %s, %d, %d}," % (
                cstr(rf["name"]), cstr(rf["unit"]), cstr(invalid_text(rf["invalid"])),
                cstr(rf["doc"]), rf["_shift"], rf["bits"]))
        lines.append("}};")
    lines.append("")


def gen_fixed_fields_pack(lines, s):
    """Writes the fixed fields of `m` to `w` in schema order (constants from the schema)."""
    for f in s["fields"]:
        sfx = SCALARS[f["_scalar"]][2]
        if "constant" in f:
            lines.append("  w.put_%s(%s);  // %s" % (sfx, constant_cpp(s, f), f["name"]))
        elif f["_count"]:
            lines.append("  for (const auto& v : m.%s) w.put_%s(v);" % (f["name"], sfx))
        else:
            lines.append("  w.put_%s(m.%s);" % (sfx, f["name"]))


def gen_fixed_fields_unpack(lines, s):
    """Reads the fixed fields from `r` into `m` in schema order, checking the length first, then
    the constants (layout version) and each field's range; the tail or repeated part is left to
    the caller."""
    msg = s["message"]
    lines.append("  if (r.remaining() < k%sFixedBytes) return DecodeError::kBadLength;" % msg)
    for f in s["fields"]:
        sfx = SCALARS[f["_scalar"]][2]
        if "constant" in f:
            lines.append("  if (r.get_%s() != %s) return DecodeError::kBadVersion;  // %s" %
                         (sfx, constant_cpp(s, f), f["name"]))
        elif f["_count"]:
            lines.append("  for (auto& v : m.%s) v = r.get_%s();" % (f["name"], sfx))
        else:
            lines.append("  m.%s = r.get_%s();" % (f["name"], sfx))
    for f in s["fields"]:
        if "max" in f:
            lines.append("  if (m.%s > %d && m.%s != %s) return DecodeError::kOutOfRange;" %
                         (f["name"], f["max"], f["name"], invalid_cpp(f["invalid"], f["_scalar"])))


def gen_tail_codec(lines, s):
    """Codec of a message whose fixed fields are followed by a byte string (`tail`) as long as
    the sum of its length fields. The struct holds the fixed fields; the tail is a span."""
    msg = s["message"]
    tail = s["tail"]
    total = " + ".join("std::size_t{m.%s}" % lf for lf in tail["length_fields"])
    lines.append("// ---- %s payload (big-endian, schema order), then the %s bytes ----" %
                 (msg, tail["name"]))
    lines.append("inline constexpr std::size_t k%sFixedBytes = %d;" % (msg, s["_fixed_bytes"]))
    lines.append("inline constexpr std::size_t k%sMaxTailBytes = %d;  ///< the %s" %
                 (msg, tail["max_bytes"], tail["name"]))
    lines.append("inline constexpr std::size_t k%sMaxPayloadBytes = %d;" % (msg, s["_max_bytes"]))
    sizes = " + ".join("sizeof(%s)%s" % (SCALARS[f["_scalar"]][0],
                                          " * %d" % f["_count"] if f["_count"] else "")
                       for f in s["fields"])
    lines.append("static_assert(k%sFixedBytes == %s, \"wire layout size\");" % (msg, sizes))
    lines.append("")
    lines.append("/// Bytes of the %s that follow the fixed fields (the sum of %s)." %
                 (tail["name"], ", ".join(tail["length_fields"])))
    lines.append("inline std::size_t tail_bytes(const %s& m) {" % msg)
    lines.append("  return %s;" % total)
    lines.append("}")
    lines.append("/// Payload bytes of this message (fixed fields and %s)." % tail["name"])
    lines.append("inline std::size_t payload_size(const %s& m) {" % msg)
    lines.append("  return k%sFixedBytes + tail_bytes(m);" % msg)
    lines.append("}")
    lines.append("")
    lines.append("/// Writes the fixed fields, then `%s`, whose size must be tail_bytes(m). 0, -ENOSPC"
                 "\n/// (writer too small) or -ERANGE (%s of another size, or above k%sMaxTailBytes)." %
                 (tail["name"], tail["name"], msg))
    lines.append("inline int pack_payload(const %s& m, std::span<const std::uint8_t> %s,"
                 " bytes::BigEndianWriter& w) {" % (msg, tail["name"]))
    lines.append("  if (%s.size() != tail_bytes(m) || %s.size() > k%sMaxTailBytes) return -ERANGE;" %
                 (tail["name"], tail["name"], msg))
    lines.append("  if (w.remaining() < payload_size(m)) return -ENOSPC;")
    gen_fixed_fields_pack(lines, s)
    lines.append("  w.put_bytes(%s);" % tail["name"])
    lines.append("  return w.ok() ? 0 : -ENOSPC;")
    lines.append("}")
    lines.append("")
    lines.append("/// Reads and validates one whole payload (`in` holds exactly one); `%s` then views"
                 "\n/// the bytes after the fixed fields inside `in`. On error `m` must not be used." %
                 tail["name"])
    lines.append("inline DecodeError unpack_payload(std::span<const std::uint8_t> in, %s& m,"
                 " std::span<const std::uint8_t>& %s) {" % (msg, tail["name"]))
    lines.append("  bytes::BigEndianReader r(in);")
    gen_fixed_fields_unpack(lines, s)
    lines.append("  if (tail_bytes(m) > k%sMaxTailBytes) return DecodeError::kOutOfRange;" % msg)
    lines.append("  if (r.remaining() != tail_bytes(m)) return DecodeError::kBadLength;")
    lines.append("  %s = in.subspan(k%sFixedBytes);" % (tail["name"], msg))
    lines.append("  return r.ok() ? DecodeError::kNone : DecodeError::kBadLength;")
    lines.append("}")
    lines.append("")


def gen_payload_codec(lines, s):
    if s.get("tail"):
        return gen_tail_codec(lines, s)
    msg = s["message"]
    rep = s.get("repeated")
    lines.append("// ---- %s payload (big-endian, schema order) ----" % msg)
    lines.append("inline constexpr std::size_t k%sFixedBytes = %d;" % (msg, s["_fixed_bytes"]))
    lines.append("inline constexpr std::size_t k%sMaxPayloadBytes = %d;" % (msg, s["_max_bytes"]))
    for f in s["fields"]:
        if "constant" in f:  # where a reader finds it in a payload of any layout version
            lines.append("inline constexpr std::size_t k%s%sOffset = %d;" %
                         (msg, snake_to_camel(f["name"]), f["_offset"]))
    if rep:
        lines.append("inline constexpr std::size_t k%sBytes = %d;" % (rep["struct"], rep["packed_bits"] // 8))
        lines.append("static_assert(k%sBytes * 8 == %d);" % (rep["struct"], rep["packed_bits"]))
        lines.append("static_assert(k%sMaxPayloadBytes == k%sFixedBytes + %d * k%sBytes);" %
                     (msg, msg, rep["max_count"], rep["struct"]))
        count_field = rep.get("count_field", "mark_count")
    # Fixed part size is checked against the per-field sizes once more in C++.
    sizes = " + ".join("sizeof(%s)%s" % (SCALARS[f["_scalar"]][0],
                                          " * %d" % f["_count"] if f["_count"] else "")
                       for f in s["fields"])
    lines.append("static_assert(k%sFixedBytes == %s, \"wire layout size\");" % (msg, sizes))
    lines.append("")
    # payload size
    lines.append("/// Payload bytes of this message on the wire (without any framing).")
    lines.append("inline std::size_t payload_size(const %s& m) {" % msg)
    if rep:
        lines.append("  const std::size_t n = m.%s <= %d ? m.%s : %d;" %
                     (count_field, rep["max_count"], count_field, rep["max_count"]))
        lines.append("  return k%sFixedBytes + n * k%sBytes;" % (msg, rep["struct"]))
    else:
        lines.append("  (void)m;")
        lines.append("  return k%sFixedBytes;" % msg)
    lines.append("}")
    lines.append("")
    # encoder
    lines.append("/// Writes the payload. 0, -ENOSPC (writer too small) or -ERANGE (a value that the"
                 " wire\n/// cannot carry: count above its maximum, a rejected mark coordinate).")
    lines.append("inline int pack_payload(const %s& m, bytes::BigEndianWriter& w) {" % msg)
    if rep:
        lines.append("  if (m.%s > %d) return -ERANGE;" % (count_field, rep["max_count"]))
    lines.append("  if (w.remaining() < payload_size(m)) return -ENOSPC;")
    gen_fixed_fields_pack(lines, s)
    if rep:
        lines.append("  for (std::size_t i = 0; i < m.%s; ++i) {" % count_field)
        lines.append("    std::uint64_t word = 0;")
        lines.append("    if (!pack_mark(m.%s[i], word)) return -ERANGE;" % rep["name"])
        lines.append("    w.put_u64(word);")
        lines.append("  }")
    lines.append("  return w.ok() ? 0 : -ENOSPC;")
    lines.append("}")
    lines.append("")
    # decoder
    lines.append("/// Reads and validates the payload; the reader must hold exactly one payload."
                 "\n/// On error `m` is partly written and must not be used.")
    lines.append("inline DecodeError unpack_payload(bytes::BigEndianReader& r, %s& m) {" % msg)
    gen_fixed_fields_unpack(lines, s)
    if rep:
        lines.append("  if (m.%s > %d) return DecodeError::kOutOfRange;" % (count_field, rep["max_count"]))
        lines.append("  if (r.remaining() != m.%s * k%sBytes) return DecodeError::kBadLength;" %
                     (count_field, rep["struct"]))
        lines.append("  for (std::size_t i = 0; i < m.%s; ++i) {" % count_field)
        lines.append("    if (!unpack_mark(r.get_u64(), m.%s[i])) return DecodeError::kOutOfRange;" % rep["name"])
        lines.append("  }")
        lines.append("  for (std::size_t i = m.%s; i < m.%s.size(); ++i) m.%s[i] = %s{};" %
                     (count_field, rep["name"], rep["name"], rep["struct"]))
    else:
        lines.append("  if (r.remaining() != 0) return DecodeError::kBadLength;")
    lines.append("  return r.ok() ? DecodeError::kNone : DecodeError::kBadLength;")
    lines.append("}")
    lines.append("")


def generate_header(schemas):
    L = []
    L.append("// GENERATED by common/msg/generate.py from common/msg/schema/*.yaml. DO NOT EDIT.")
    L.append("// Wire message definitions of storetrack (docs/icd.md). Byte order: big-endian.")
    L.append("#pragma once")
    L.append("")
    for inc in ["<algorithm>", "<array>", "<cerrno>", "<cmath>", "<cstddef>", "<cstdint>",
                "<limits>", "<span>", "<string_view>"]:
        L.append("#include %s" % inc)
    L.append("")
    L.append('#include "storetrack/bytes/byte_cursor.hpp"')
    L.append('#include "storetrack/msg/decode_error.hpp"')
    L.append("")
    L.append("namespace storetrack::msg {")
    L.append("")
    L.append("/// Message ids (UDP header `message id`, CAN FD identifier FID field).")
    L.append("enum class MessageId : std::uint8_t {")
    for s in schemas:
        L.append("  k%s = 0x%02X,  ///< version %d" % (s["message"], s["id"], s["version"]))
    L.append("};")
    for s in schemas:
        L.append("inline constexpr std::uint8_t k%sVersion = %d;" % (s["message"], s["version"]))
    L.append("")
    L.append("/// Per-field metadata (for CSV writers, displays, the ICD).")
    L.append("struct FieldInfo {")
    L.append("  std::string_view name, type, unit, frame, invalid, doc;")
    L.append("  std::uint16_t offset;  ///< byte offset in the payload")
    L.append("  std::uint16_t size;    ///< bytes")
    L.append("};")
    L.append("struct BitFieldInfo {")
    L.append("  std::string_view name, unit, invalid, doc;")
    L.append("  std::uint8_t shift, bits;  ///< position in the packed word (LSB = bit 0)")
    L.append("};")
    L.append("")
    # flags
    for s in schemas:
        for f in s["fields"]:
            if "bits" in f:
                ns = FLAG_NAMESPACES[(s["message"], f["name"])]
                gen_flag_namespace(L, ns, f["bits"], SCALARS[f["_scalar"]][0],
                                   "%s.%s bits: %s" % (s["message"], f["name"], f["doc"]))
        rep = s.get("repeated")
        if rep:
            for rf in rep["fields"]:
                if "flag_bits" in rf:
                    ns = FLAG_NAMESPACES[(rep["struct"], rf["name"])]
                    gen_flag_namespace(L, ns, rf["flag_bits"], CPP_OF_STRUCT_TYPE[rf["type"]],
                                       "%s.%s bits: %s" % (rep["struct"], rf["name"], rf["doc"]))
    # structs
    for s in schemas:
        rep = s.get("repeated")
        if rep:
            L.append("/// %s" % rep["doc"])
            L.append("struct %s {" % rep["struct"])
            for rf in rep["fields"]:
                L.append("  %s %s{};  ///< [%s] %s" % (CPP_OF_STRUCT_TYPE[rf["type"]], rf["name"],
                                                      rf["unit"], rf["doc"]))
            L.append("};")
            L.append("inline constexpr std::size_t kMax%s = %d;" % (
                snake_to_camel(rep["name"]), rep["max_count"]))
            L.append("")
        L.append("/// %s" % " ".join(s["doc"].split()))
        L.append("struct %s {" % s["message"])
        for f in member_fields(s):
            cpp = SCALARS[f["_scalar"]][0]
            if f["_count"]:
                cpp = "std::array<%s, %d>" % (cpp, f["_count"])
            L.append("  %s %s{};  ///< [%s] %s" % (cpp, f["name"], f["unit"], f["doc"]))
        if rep:
            L.append("  std::array<%s, %d> %s{};  ///< first mark_count are valid" %
                     (rep["struct"], rep["max_count"], rep["name"]))
        L.append("};")
        L.append("")
        L.append("/// Invalid (\"not available\") values per field, from the schema.")
        L.append("namespace %s_invalid {" % camel_to_snake(s["message"]))
        for f in member_fields(s):
            if f["invalid"] == "-":  # no invalid value (a digest, a byte array)
                continue
            L.append("inline constexpr %s k%s = %s;" % (SCALARS[f["_scalar"]][0],
                                                      snake_to_camel(f["name"]),
                                                      invalid_cpp(f["invalid"], f["_scalar"])))
        L.append("}  // namespace %s_invalid" % camel_to_snake(s["message"]))
        L.append("")
    for s in schemas:
        gen_field_info(L, s)
    for s in schemas:
        if s.get("repeated"):
            gen_mark_codec(L, s)
    for s in schemas:
        gen_payload_codec(L, s)
    # The largest message on a link (UDP, CAN FD): recording-only messages never travel there.
    L.append("inline constexpr std::size_t kMaxPayloadBytes = std::max({%s});" %
             ", ".join("k%sMaxPayloadBytes" % s["message"] for s in schemas
                       if not s.get("recording_only")))
    L.append("")
    L.append("}  // namespace storetrack::msg")
    L.append("")
    return "\n".join(L)


# ------------------------------------------------------------------------------------------
# ICD tables
# ------------------------------------------------------------------------------------------
def md(s):
    return str(s).replace("|", "\\|")


def icd_blocks(schemas):
    """name -> markdown of each generated block."""
    blocks = {}
    for s in schemas:
        msg = s["message"]
        rows = ["%s (message id 0x%02X, version %d): %s" % (msg, s["id"], s["version"],
                                                             " ".join(s["doc"].split())), "",
                "| Offset | Size | Field | Type | Unit | Frame | Invalid | Description |",
                "|---:|---:|---|---|---|---|---|---|"]
        for f in s["fields"]:
            extra = ""
            if "max" in f:
                extra = " (valid: 0..%d or the invalid value)" % f["max"]
            if "constant" in f:
                extra = " (always %d, the message version; a decoder refuses any other)" % s["version"]
            rows.append("| %d | %d | `%s` | %s | %s | %s | %s | %s%s |" % (
                f["_offset"], f["_size"], f["name"], f["type"], md(f["unit"]), md(f["frame"]),
                invalid_text(f["invalid"]), md(f["doc"]), extra))
        rep = s.get("repeated")
        if rep:
            rows.append("| %d | 8 x `%s` | `%s` | u64[] | | | | %s (see the mark word table) |" % (
                s["_fixed_bytes"], "mark_count", rep["name"], md(rep["doc"])))
            rows.append("")
            rows.append("Payload size: %d + 8 x mark_count bytes, at most %d bytes (mark_count <= %d)."
                        % (s["_fixed_bytes"], s["_max_bytes"], rep["max_count"]))
        elif s.get("tail"):
            tail = s["tail"]
            rows.append("| %d | %s | `%s` | u8[] | bytes | - | - | %s |" % (
                s["_fixed_bytes"], " + ".join("`%s`" % lf for lf in tail["length_fields"]),
                tail["name"], md(tail["doc"])))
            rows.append("")
            rows.append("Payload size: %d + %s bytes, at most %d bytes (%s <= %d)." % (
                s["_fixed_bytes"], " + ".join(tail["length_fields"]), s["_max_bytes"],
                tail["name"], tail["max_bytes"]))
            if s.get("recording_only"):
                rows.append("")
                rows.append("Recording only: never sent on a link (UDP or CAN FD); "
                            "docs/fti-output.md, \"IRIG 106 Chapter 10 file\".")
        else:
            rows.append("")
            rows.append("Payload size: %d bytes." % s["_fixed_bytes"])
        for f in s["fields"]:
            if "bits" in f:
                rows += ["", "`%s.%s` bits (%s, C++ `%s::k...`):" % (
                    msg, f["name"], f["type"], FLAG_NAMESPACES[(msg, f["name"])]), "",
                         "| Bit | Mask | Name | Meaning |", "|---:|---:|---|---|"]
                for b in f["bits"]:
                    rows.append("| %d | 0x%04X | `%s` | %s |" % (b["bit"], 1 << b["bit"], b["name"],
                                                               md(b["doc"])))
        blocks["schema:" + camel_to_snake(msg)] = "\n".join(rows)
        if rep:
            w = ["`%s` word (%d bits, sent as one big-endian u64; bit 63 is the first bit on the "
                 "wire):" % (rep["struct"], rep["packed_bits"]), "",
                 "| Bits | Width | Field | Encoding | Unit | Frame | Invalid code | Description |",
                 "|---|---:|---|---|---|---|---|---|"]
            for rf in rep["fields"]:
                enc = rf.get("encoding", "linear" if "scale" in rf else "raw")
                if "flag_bits" in rf:
                    e = "bitfield"
                elif enc == "log2":
                    e = "value = %g x 2^(code x %g); %s" % (rf["log_base"], rf["log_step"],
                                                            rf.get("overflow", "saturate"))
                else:
                    off = rf.get("offset", 0.0)
                    e = "value = code x %g%s; %s" % (
                        rf["scale"], (" %s %g" % ("-" if off < 0 else "+", abs(off))) if off else "",
                        rf.get("overflow", "saturate"))
                w.append("| %d..%d | %d | `%s` | %s | %s | %s | 0x%X | %s |" % (
                    rf["_shift"] + rf["bits"] - 1, rf["_shift"], rf["bits"], rf["name"], md(e),
                    md(rf["unit"]), md(rf["frame"]), rf["invalid"], md(rf["doc"])))
            for rf in rep["fields"]:
                if "flag_bits" in rf:
                    w += ["", "`%s.%s` bits (C++ `%s::k...`):" % (
                        rep["struct"], rf["name"], FLAG_NAMESPACES[(rep["struct"], rf["name"])]), "",
                          "| Bit | Mask | Name | Meaning |", "|---:|---:|---|---|"]
                    for b in rf["flag_bits"]:
                        w.append("| %d | 0x%X | `%s` | %s |" % (b["bit"], 1 << b["bit"], b["name"],
                                                              md(b["doc"])))
            blocks["schema:" + camel_to_snake(rep["struct"]) + "_word"] = "\n".join(w)
    return blocks


BLOCK_RE = re.compile(r"(<!-- BEGIN GENERATED (schema:[\w]+) -->\n)(.*?)(<!-- END GENERATED \2 -->)",
                      re.S)


def render_icd(text, blocks):
    seen = set()

    def repl(m):
        name = m.group(2)
        if name not in blocks:
            fail("docs block %s has no schema counterpart" % name)
        seen.add(name)
        return m.group(1) + blocks[name] + "\n" + m.group(4)

    out = BLOCK_RE.sub(repl, text)
    missing = sorted(set(blocks) - seen)
    return out, missing


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--schema-dir", default=os.path.join(HERE, "schema"))
    ap.add_argument("--header", help="write messages.hpp here")
    ap.add_argument("--check-icd", metavar="ICD_MD", help="fail when the ICD tables drifted")
    ap.add_argument("--update-icd", metavar="ICD_MD", help="rewrite the ICD tables in place")
    ap.add_argument("--check-doc", metavar="MD", action="append", default=[],
                    help="like --check-icd for another document, over the blocks it holds")
    ap.add_argument("--update-doc", metavar="MD", action="append", default=[],
                    help="like --update-icd for another document, over the blocks it holds")
    ap.add_argument("--print-icd", action="store_true", help="print the generated blocks")
    args = ap.parse_args()
    schemas = load_schemas(args.schema_dir)
    if args.header:
        text = generate_header(schemas)
        old = None
        if os.path.exists(args.header):
            with open(args.header) as fh:
                old = fh.read()
        if old != text:  # keep the timestamp when unchanged: no needless rebuilds
            os.makedirs(os.path.dirname(os.path.abspath(args.header)), exist_ok=True)
            with open(args.header, "w") as fh:
                fh.write(text)
    blocks = icd_blocks(schemas)
    if args.print_icd:
        for name, b in blocks.items():
            print("<!-- BEGIN GENERATED %s -->\n%s\n<!-- END GENERATED %s -->\n" % (name, b, name))
    docs = [(args.check_icd, False, True), (args.update_icd, True, True)]
    docs += [(p, False, False) for p in args.check_doc] + [(p, True, False) for p in args.update_doc]
    for path, update, whole_icd in docs:
        if not path:
            continue
        with open(path) as fh:
            text = fh.read()
        out, missing = render_icd(text, blocks)
        if not whole_icd:  # another document: the blocks it holds, at least one
            if len(missing) == len(blocks):
                sys.stderr.write("%s holds no generated schema block\n" % path)
                return 1
            missing = []
        if update:
            if missing:
                out += "".join("\n<!-- BEGIN GENERATED %s -->\n%s\n<!-- END GENERATED %s -->\n" %
                               (n, blocks[n], n) for n in missing)
            if out != text:
                with open(path, "w") as fh:
                    fh.write(out)
                print("updated %s" % path)
        else:
            bad = False
            if missing:
                sys.stderr.write("%s lacks generated blocks: %s\n" % (path, ", ".join(missing)))
                bad = True
            if out != text:
                sys.stderr.write("%s drifted from the schema; run: python3 %s --update-icd %s\n" %
                                 (path, os.path.relpath(__file__), path))
                sys.stderr.writelines(difflib.unified_diff(
                    text.splitlines(True), out.splitlines(True), path, "generated"))
                bad = True
            if bad:
                return 1
            print("%s matches the schema" % path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
