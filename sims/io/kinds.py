"""What kind of file a path holds, told from its first bytes, and which command reads that kind.

Every reader of a project file calls :func:`require_kind` before parsing, so that a file of another
kind (an image given to ``localize``, an ensemble ``.npz`` given to ``score`` as the estimate of a
log, a detections file given where a rig file belongs) is refused with what it is, what was
expected, and the command that reads what was given, instead of a parser's complaint about its
bytes. Only the first :data:`HEAD_BYTES` are read, with the standard library alone; a file whose
kind cannot be told passes, and the reader's own checks report what is wrong with it.
"""

from __future__ import annotations

import ast
import os
import re
import zipfile

from decentral.errors import InputError

__all__ = ["HEAD_BYTES", "KINDS", "describe", "require_folder", "require_kind", "sniff"]

#: bytes read to tell a file's kind
HEAD_BYTES = 65536

#: kind -> (what it is, what reads it). The ``decentral.*`` kinds are the ``format`` fields of the
#: project's files (a test keeps them equal to the readers' constants); the others are told by magic bytes.
KINDS: dict[str, tuple[str, str]] = {
    "decentral.log/1": ("an observation log (decentral.log/1)",
                        "`decentral localize`, `decentral launch` and `decentral parts` read logs"),
    "decentral.estimate/1": ("an estimate (decentral.estimate/1)",
                             "`decentral score EST TRUTH` and `decentral export` read estimates"),
    "decentral.truth/1": ("a ground truth (decentral.truth/1)",
                          "`decentral score EST TRUTH` (as TRUTH) and `decentral export` read truths"),
    "decentral.detections/1": ("a detections file (decentral.detections/1)",
                               "`decentral build-log` reads it through a rig file (RIG.toml)"),
    "decentral.rig/1": ("a rig file (decentral.rig/1)", "`decentral build-log` reads rig files"),
    "decentral.layout/1": ("a layout file (decentral.layout/1)",
                           "`decentral build-log` reads it through a rig file (RIG.toml)"),
    "decentral.ensemble/1": ("ensemble observations (decentral.ensemble/1)", "use `decentral ensemble`"),
    "decentral.ensemble_estimate/1": ("an ensemble estimate (decentral.ensemble_estimate/1)",
                                      "`decentral score EST TRUTH` reads it with its ensemble truth"),
    "decentral.ensemble_truth/1": ("an ensemble truth (decentral.ensemble_truth/1)",
                                   "`decentral score EST TRUTH` reads it as TRUTH"),
    "decentral.peers/1": ("a peers file (decentral.peers/1)", "`decentral agent --peers` reads it"),
    "decentral.key/1": ("a private key (decentral.key/1)", "`decentral agent --key` reads it"),
    "decentral.pubkey/1": ("a public key (decentral.pubkey/1)", "a peers file names it"),
    "study-spec": ("a study specification (TOML with [grid])", "`decentral study` reads it"),
    "image": ("an image", "`decentral perceive` reads images"),
    "video": ("a video", "`decentral perceive` reads videos"),
    "sqlite": ("an SQLite database", "`decentral report DIR` reads a study's DIR/study.sqlite"),
    "rosbag": ("a ROS bag", "`decentral build-log` reads it through a rig file (RIG.toml)"),
    # expected only (nothing tells them from their bytes): plain JSON that the options name
    "tag-table": ("a tag table (JSON object: tag id -> node id)", "`decentral perceive --tag-table` reads it"),
}

_IMAGE_MAGIC = (b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff", b"GIF87a", b"GIF89a", b"BM", b"II*\x00", b"MM\x00*")
_JSON_FORMAT = re.compile(rb'"format"\s*:\s*"([A-Za-z0-9._/-]{1,64})"')
_TOML_FORMAT = re.compile(rb'^\s*format\s*=\s*"([A-Za-z0-9._/-]{1,64})"', re.MULTILINE)
_TOML_GRID = re.compile(rb"^\s*\[grid\]\s*$", re.MULTILINE)
#: largest ``format.npy`` member read from an ``.npz`` (a format string is a few dozen bytes)
_MAX_FORMAT_MEMBER = 4096


def sniff(path: str | os.PathLike) -> str | None:
    """The kind of the file at ``path`` (a key of :data:`KINDS`), or None when it cannot be told.

    Never raises: a missing or unreadable file is None (its reader says what is wrong).
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(HEAD_BYTES)
    except (OSError, ValueError):
        return None
    if head.startswith(_IMAGE_MAGIC) or (head[:4] == b"RIFF" and head[8:12] == b"WEBP"):
        return "image"
    if (head[:4] == b"RIFF" and head[8:12] == b"AVI ") or head[4:8] == b"ftyp" or head[:4] == b"\x1aE\xdf\xa3":
        return "video"
    if head.startswith(b"SQLite format 3\x00"):
        return "sqlite"
    if head.startswith(b"#ROSBAG"):
        return "rosbag"
    if head.startswith(b"PK\x03\x04"):
        return _npz_format(path)
    pattern = _JSON_FORMAT if head.lstrip()[:1] == b"{" else _TOML_FORMAT
    for match in pattern.finditer(head):  # the first known one: a nested "format" may name something else
        kind = match.group(1).decode("ascii")
        if kind in KINDS:
            return kind
    if _TOML_GRID.search(head):
        return "study-spec"
    return None


def _npz_format(path: str | os.PathLike) -> str | None:
    """The ``format`` string stored in an ``.npz`` archive (its ``format.npy`` member), if it is a known kind."""
    try:
        with zipfile.ZipFile(path) as archive:
            info = archive.getinfo("format.npy")
            if info.file_size > _MAX_FORMAT_MEMBER:
                return None
            with archive.open(info) as fh:
                raw = fh.read(_MAX_FORMAT_MEMBER)
        if not raw.startswith(b"\x93NUMPY"):
            return None
        size_bytes = 2 if raw[6] == 1 else 4
        size = int.from_bytes(raw[8:8 + size_bytes], "little")
        start = 8 + size_bytes
        header = ast.literal_eval(raw[start:start + size].decode("latin-1"))
        descr, data = str(header["descr"]), raw[start + size:]
        if descr.startswith(("<U", "|U")):
            text = data.decode("utf-32-le")
        elif descr.startswith(("|S", "S")):
            text = data.decode("ascii")
        else:
            return None
        text = text.rstrip("\x00")
    except (OSError, KeyError, ValueError, SyntaxError, TypeError, IndexError, zipfile.BadZipFile, RuntimeError,
            UnicodeDecodeError, NotImplementedError, EOFError, MemoryError, RecursionError):
        return None
    return text if text in KINDS else None


def describe(kind: str) -> str:
    """What a kind of file is, in words (``an image``, ``an observation log (decentral.log/1)``)."""
    return KINDS[kind][0]


def require_kind(path: str | os.PathLike, *expected: str, field: str | None = None) -> None:
    """Refuse ``path`` when it is plainly a known kind other than ``expected`` (keys of :data:`KINDS`).

    Raises
    ------
    InputError
        Naming the file (and ``field``: by default ``format`` when that field told the kind): what it is,
        what was expected, and which command reads what was given.
    """
    kind = sniff(path)
    if kind is None or kind in expected:
        return
    what, reader = KINDS[kind]
    if field is None and kind.startswith("decentral."):
        field = "format"
    wanted = " or ".join(describe(e) for e in expected)
    raise InputError(f"this is {what}, not {wanted}; {reader}", source=str(path), field=field)


def require_folder(path: str | os.PathLike, holds: str) -> None:
    """Refuse a file given where a folder holding ``holds`` belongs, saying what the file is and what reads it.

    Raises
    ------
    InputError
        Naming the file; a missing path or a folder passes (the reader says what is wrong with it).
    """
    if not os.path.isfile(path):
        return
    kind = sniff(path)
    what, reader = KINDS[kind] if kind else ("a file", "")
    raise InputError(f"this is {what}, not a folder holding {holds}" + (f"; {reader}" if reader else ""),
                     source=str(path))
