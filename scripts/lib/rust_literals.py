"""Numbers written as Rust source: the shortest decimal that reads back as the same f32, so
that generated tables pass clippy's `excessive_precision` and round-trip exactly."""
import struct


def f32_literal(v):
    """`v` rounded to f32, as the shortest Rust float literal that parses back to it."""
    v = struct.unpack("f", struct.pack("f", v))[0]
    for digits in range(1, 10):
        text = f"{v:.{digits}g}"
        if struct.unpack("f", struct.pack("f", float(text)))[0] == v:
            break
    return text if any(c in text for c in ".e") else text + ".0"
