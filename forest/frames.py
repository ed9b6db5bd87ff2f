"""Frame specs and frame-numbered file names, read with :mod:`fileseq` (the VFX pipelines' own parser).

A frame spec (``--frames``) is a :class:`fileseq.FrameSet`: ``5``, ``1-120``,
``1-120x5`` (every 5th), ``1,5,9-12`` (a list), ``1-10y3`` (the frames
``1-10x3`` leaves out), ``1-10:3`` (staggered); the result is the sorted set of
whole frames.  A range that runs backwards (``9-1``), a fraction, an empty
entry or more than :data:`MAX_FRAMES` frames is refused.

A frame pattern (``-o``) names one file per frame with one padding token, as
the studio tools write them (frame 7 shown):

* ``####`` → ``0007``, one ``#`` a digit (forest, Nuke, RenderMan);
* ``@@@@`` → ``0007``, one ``@`` a digit (fileseq, Katana);
* ``%04d`` → ``0007``, ``%d`` → ``7`` (printf: Nuke, ffmpeg);
* ``$F4`` → ``0007``, ``$F`` → ``7`` (Houdini).

A pattern without a token gets ``_0007`` before its extension.  A still (no
``--frames``) written to a pattern is frame 1 named by it, as Nuke and Houdini
render the current frame through the pattern (:func:`still_path`).  Any other
``%``, ``$`` or ``<…>`` token in the file name (``%s``, ``%4x``, ``$T``, ``<UDIM>``), or two
tokens, is refused: it would otherwise end up, unexpanded, in every file's name.
"""

from __future__ import annotations

import re

import fileseq

from .errors import ParameterError

#: Most frames one spec may select.
MAX_FRAMES = 100_000

#: What every refused spec is told to look like.
_SPEC_HINT = "use e.g. 1-120, 1-120x5 or 1,5,9-12"
#: What every refused pattern is told to use.
_PATTERN_HINT = "use ####, @@@@, %04d or $F4 for the frame number"

#: The padding tokens fileseq reads (``fileseq.getPaddingNum``), and any other ``%…`` or ``$…`` (to refuse).
_TOKEN = re.compile(r"#+|@+|%\d*d|\$F\d*(?!\w)|(?P<bad>%\w*|\$\{?\w*\}?|<\w+>)")


def parse_frames(spec: str) -> list[int]:
    """``"1-120"``, ``"1-120x5"`` (every 5th), ``"5"``, ``"1,5,9-12"`` → the sorted unique frames.

    Read by :class:`fileseq.FrameSet`; a :class:`ParameterError` on ``frames``
    for anything it cannot read, a backwards range, a fraction or more than
    :data:`MAX_FRAMES` frames.
    """
    text = str(spec).strip()
    if not text or "#" in text or "@" in text:  # fileseq would drop padding characters silently
        raise ParameterError("frames", f"cannot read {spec!r}; {_SPEC_HINT}")
    parts = [_frame_set(part.strip(), spec) for part in text.split(",")]
    total = fileseq.FrameSet(text) if len(parts) > 1 else parts[0]
    if len(total) > MAX_FRAMES:
        raise ParameterError("frames", f"{spec!r} selects more than {MAX_FRAMES} frames")
    return sorted({int(f) for f in total})


def _frame_set(part: str, spec: str) -> fileseq.FrameSet:
    """One comma-separated entry of ``spec`` as a FrameSet: whole frames, not running backwards."""
    try:
        fs = fileseq.FrameSet(part) if part else None
    except fileseq.MaxSizeException:
        raise ParameterError("frames", f"range {part!r} has more than {MAX_FRAMES} frames") from None
    except fileseq.ParseException:
        fs = None
    if fs is None or len(fs) == 0 or fs.hasSubFrames():
        raise ParameterError("frames", f"cannot read {spec!r}; {_SPEC_HINT}")
    if fs.start() > fs.end():
        raise ParameterError("frames", f"bad range {part!r}")
    if len(fs) > MAX_FRAMES:
        raise ParameterError("frames", f"range {part!r} has more than {MAX_FRAMES} frames")
    return fs


def _token(pattern: str) -> re.Match[str] | None:
    """The one frame token in ``pattern`` (None: none); a :class:`ParameterError` on ``output`` for an unknown
    ``%``/``$`` token in the file name or for two tokens."""
    name_start = max(pattern.rfind("/"), pattern.rfind("\\")) + 1
    found = []
    for m in _TOKEN.finditer(pattern):
        if m.group("bad") is not None:
            if m.start() >= name_start:  # a folder may hold a % or $; only the file name is a pattern
                raise ParameterError("output", f"{pattern}: unknown frame token {m.group()!r}; {_PATTERN_HINT}")
            continue
        found.append(m)
    if len(found) > 1:
        tokens = ", ".join(repr(m.group()) for m in found)
        raise ParameterError("output", f"{pattern}: more than one frame token ({tokens}); {_PATTERN_HINT}")
    return found[0] if found else None


def frame_token(pattern: str) -> tuple[int, int] | None:
    """Where the frame token of ``pattern`` is (``(start, end)``; None: it has none).

    A :class:`ParameterError` on ``output`` for a pattern :func:`frame_path` cannot expand.
    """
    m = _token(str(pattern))
    return None if m is None else m.span()


def frame_path(pattern: str, frame: int) -> str:
    """``pattern`` with its frame token replaced by ``frame``, zero-padded to the token's width.

    ``f_####.exr``, ``f.@@@@.exr``, ``f.%04d.exr`` and ``f.$F4.exr`` give
    ``f_0007.exr`` … ``f.0007.exr`` for frame 7 (the width from
    ``fileseq.getPaddingNum``, one digit per ``#`` or ``@``); a pattern
    without a token gets ``_0007`` before its extension.
    """
    pattern = str(pattern)
    m = _token(pattern)
    if m is None:
        stem, dot, ext = pattern.rpartition(".")
        return f"{stem}_{frame:04d}.{ext}" if dot else f"{pattern}_{frame:04d}"
    width = fileseq.getPaddingNum(m.group(), fileseq.PAD_STYLE_HASH1)
    return pattern[: m.start()] + f"{frame:0{width}d}" + pattern[m.end() :]


def still_path(output: str) -> str:
    """Where a still (frame 1) goes: ``output`` with its frame token filled in (``f.%04d.exr`` → ``f.0001.exr``),
    as Nuke and Houdini render the current frame through the pattern; ``output`` as given when it has no token."""
    return str(output) if frame_token(str(output)) is None else frame_path(str(output), 1)
