"""LZF (liblzf) block compression, as used by PCD ``binary_compressed`` data.

Format (liblzf ``lzf_d.c`` documentation): a stream of tokens, each starting with a control
byte ``ctrl``:

- ``ctrl < 32``: a literal run; the next ``ctrl + 1`` bytes are copied as they are.
- otherwise a back reference: ``length = ctrl >> 5`` (7 means "add the next byte"), then one
  more byte ``lo``; copy ``length + 2`` bytes starting ``((ctrl & 31) << 8) + lo + 1`` bytes back
  in the output (the copy may overlap what it writes, like run-length encoding).

The compressor is a greedy single-pass matcher over 3-byte prefixes (the same token format, so
any LZF decoder reads it). Both run in pure Python; literal-heavy float data decode at tens of
MB/s, compression is slower (~1-2 MB/s) and only used by writers.
"""

from __future__ import annotations

__all__ = ["lzf_decompress", "lzf_compress", "LzfError"]

_MAX_LIT = 32
_MAX_OFF = 1 << 13  # 8192
_MAX_REF = (1 << 8) + (1 << 3)  # 264 bytes: 7 + 255 + 2


class LzfError(ValueError):
    """The compressed stream is corrupt or does not decode to the expected size."""


def lzf_decompress(data: bytes, expected_size: int) -> bytes:
    """Decode an LZF block that must expand to exactly ``expected_size`` bytes."""
    src = bytes(data)
    n = len(src)
    out = bytearray(expected_size)
    o = i = 0
    try:
        while i < n:
            ctrl = src[i]
            i += 1
            if ctrl < 32:  # literal run
                j = i + ctrl + 1
                e = o + ctrl + 1
                if j > n or e > expected_size:
                    raise LzfError(
                        f"literal run at input offset {i - 1} passes the end of the data or output"
                    )
                out[o:e] = src[i:j]
                i, o = j, e
                continue
            length = ctrl >> 5
            if length == 7:
                length += src[i]
                i += 1
            start = o - (((ctrl & 0x1F) << 8) | src[i]) - 1
            i += 1
            length += 2
            e = o + length
            if start < 0 or e > expected_size:
                raise LzfError(f"back reference at input offset {i - 2} points outside the output")
            if o - start >= length:
                out[o:e] = out[start : start + length]
            else:  # overlapping copy: the last (o - start) bytes repeat
                pattern = bytes(out[start:o])
                reps, rest = divmod(length, o - start)
                out[o:e] = pattern * reps + pattern[:rest]
            o = e
    except IndexError:
        raise LzfError("stream ends inside a back reference") from None
    if o != expected_size:
        raise LzfError(f"decompressed to {o} bytes, expected {expected_size}")
    return bytes(out)


def lzf_compress(data: bytes) -> bytes:
    """Encode ``data`` as an LZF block (greedy matching over 3-byte prefixes)."""
    src = bytes(data)
    n = len(src)
    out = bytearray()
    table: dict[bytes, int] = {}
    lit_start = 0
    i = 0

    def flush_literals(end: int) -> None:
        s = lit_start
        while s < end:
            run = min(_MAX_LIT, end - s)
            out.append(run - 1)
            out.extend(src[s : s + run])
            s += run

    while i + 2 < n:
        key = src[i : i + 3]
        ref = table.get(key)
        table[key] = i
        if ref is not None and i - ref <= _MAX_OFF:
            max_len = min(_MAX_REF, n - i)
            length = 3
            while length < max_len and src[ref + length] == src[i + length]:
                length += 1
            flush_literals(i)
            off = i - ref - 1
            code = length - 2
            if code < 7:
                out.append((code << 5) | (off >> 8))
            else:
                out.append((7 << 5) | (off >> 8))
                out.append(code - 7)
            out.append(off & 0xFF)
            # index a few positions inside the match so later repeats are found
            for k in range(i + 1, min(i + length, n - 2)):
                table[src[k : k + 3]] = k
            i += length
            lit_start = i
        else:
            i += 1
    flush_literals(n)
    return bytes(out)
