"""The ``rlpkg`` command-line program from Python: finding the binary and reading the TensorBoard
scalars ``rlpkg train`` writes into its run folder (``<run>/events.out.tfevents.*``)."""

from __future__ import annotations

import os
import struct
from pathlib import Path

from rlpkg import _native

__all__ = ["find_binary", "scalars"]


def find_binary() -> Path:
    """The ``rlpkg`` executable: ``$RLPKG_BIN``, else ``$CARGO_TARGET_DIR/release/rlpkg``, else
    ``target/release/rlpkg`` of the repository the package was built from."""
    candidates = []
    if os.environ.get("RLPKG_BIN"):
        path = Path(os.environ["RLPKG_BIN"])
        if not (path.is_file() and os.access(path, os.X_OK)):
            raise FileNotFoundError(f"RLPKG_BIN={path}: no such executable file")
        return path
    if os.environ.get("CARGO_TARGET_DIR"):
        candidates.append(Path(os.environ["CARGO_TARGET_DIR"]) / "release" / "rlpkg")
    candidates.append(Path(_native.REPOSITORY).resolve() / "target" / "release" / "rlpkg")
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return path
    raise FileNotFoundError(
        "no rlpkg executable: set RLPKG_BIN to its path, or build it with `cargo build --release` "
        f"(looked for {', '.join(str(p) for p in candidates)})"
    )


def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[i]
        i += 1
        value |= (byte & 0x7F) << shift
        if byte < 0x80:
            return value, i
        shift += 7


def _fields(data: bytes):
    """(field number, wire type, value) of a protobuf message (value: int or bytes)."""
    i = 0
    while i < len(data):
        key, i = _varint(data, i)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(data, i)
        elif wire == 1:
            value, i = data[i : i + 8], i + 8
        elif wire == 2:
            n, i = _varint(data, i)
            value, i = data[i : i + n], i + n
        elif wire == 5:
            value, i = data[i : i + 4], i + 4
        else:
            raise ValueError(f"protobuf wire type {wire}: not in a TensorBoard scalar event")
        yield field, wire, value


def scalars(run_dir: str | os.PathLike) -> dict[str, list[tuple[int, float]]]:
    """Every scalar of a run folder's TensorBoard event files: ``{tag: [(step, value), ...]}``
    in the order written (``charts/episodic_return``, ``losses/value_loss``, ...)."""
    files = sorted(Path(run_dir).glob("events.out.tfevents.*"))
    if not files:
        raise FileNotFoundError(f"{run_dir}: no events.out.tfevents.* file (not an rlpkg run folder?)")
    out: dict[str, list[tuple[int, float]]] = {}
    for path in files:
        try:
            _read_scalars(path.read_bytes(), out)
        except (ValueError, IndexError, struct.error, UnicodeDecodeError) as e:
            raise ValueError(f"{path}: not a TensorBoard event file of scalars ({e})") from e
    return out


def _read_scalars(data: bytes, out: dict[str, list[tuple[int, float]]]) -> None:
    """Adds the scalars of one event file's bytes ``data`` to ``out``."""
    i = 0
    # TFRecord: u64 length, u32 CRC of the length, the Event message, u32 CRC of the message.
    while i + 12 <= len(data):
        (length,) = struct.unpack_from("<Q", data, i)
        event = data[i + 12 : i + 12 + length]
        i += 12 + length + 4
        step = 0
        summaries = []
        for field, _, value in _fields(event):
            if field == 2:
                step = value
            elif field == 5:
                summaries.append(value)
        for summary in summaries:
            for field, _, value in _fields(summary):
                if field != 1:
                    continue
                tag, number = None, None
                for f, wire, v in _fields(value):
                    if f == 1:
                        tag = v.decode()
                    elif f == 2 and wire == 5:
                        (number,) = struct.unpack("<f", v)
                if tag is not None and number is not None:
                    out.setdefault(tag, []).append((step, number))
