# Numbered file sequences (SPEC §10 "Sequences"): the frame number in a file name, the frames on
# disk, which file a scene frame shows, a small LRU cache of parsed frames, and the heat-map range
# of a whole sequence from its summary JSON or from the frames themselves. No bpy, so it runs and
# is tested outside Blender too.
#
# A pattern is a path whose file name holds a run of '#' (Houdini's $F4, Blender's ####) or a
# printf %0Nd: the frame number padded with zeros to N digits (a wider number is written whole,
# frame 12345 of `####` is 12345). Given one file of a set, the last run of digits in its name
# (before the extension) is the frame number, as Blender's own volume and image sequences read it.

import json
import math
import os
import re
from collections import OrderedDict
from dataclasses import dataclass, field

MODES = ("CLIP", "EXTEND", "REPEAT", "PING_PONG")   # Blender's volume sequence_mode names
_PLACEHOLDER = re.compile(r"(#+)|%(0?)(\d*)d")
_LAST_DIGITS = re.compile(r"(\d+)(?!.*\d)")
MAX_SUMMARY_BYTES = 64 << 20
MAX_SUMMARY_FILES = 64


class SequenceError(ValueError):
    """Not a numbered sequence, or no frame of it on disk; the message says why in one line."""


@dataclass
class Sequence:
    """Files directory/prefix<frame padded to width>suffix, and the frames that exist."""
    directory: str
    prefix: str
    suffix: str
    width: int
    frames: list = field(default_factory=list)      # sorted frame numbers on disk

    def name(self, frame):
        return f"{self.prefix}{frame:0{self.width}d}" if frame >= 0 else \
            f"{self.prefix}-{-frame:0{self.width}d}"

    def path(self, frame):
        return os.path.join(self.directory, self.name(frame) + self.suffix)

    @property
    def pattern(self):
        """The path with '#' for the frame number (what `isouq mesh` reads and writes)."""
        return os.path.join(self.directory, self.prefix + "#" * self.width + self.suffix)

    @property
    def first(self):
        return self.frames[0]

    @property
    def last(self):
        return self.frames[-1]

    def matches(self, filename):
        """The frame number of `filename` if it belongs to the sequence, else None."""
        if not (filename.startswith(self.prefix) and filename.endswith(self.suffix)):
            return None
        digits = filename[len(self.prefix):len(filename) - len(self.suffix)]
        if not digits.isdigit() or not digits.isascii():
            return None
        frame = int(digits)
        return frame if self.name(frame) + self.suffix == filename else None

    def scan(self):
        """Re-reads the frames on disk; returns self."""
        try:
            names = os.listdir(self.directory or ".")
        except OSError as e:
            raise SequenceError(f"cannot list {self.directory!r}: {e.strerror}") from None
        self.frames = sorted(f for f in (self.matches(n) for n in names) if f is not None)
        return self

    def file_frame(self, scene_frame, offset=0, mode="EXTEND"):
        """The frame on disk that scene frame `scene_frame` shows, or None (empty).

        File frame n = scene frame + offset. Before the first or after the last frame: CLIP
        shows nothing, EXTEND holds the nearest end, REPEAT loops, PING_PONG loops back and forth
        (Blender's volume sequence modes). Inside the range, a frame that is not on disk (a step
        or a gap) holds the last frame before it."""
        if not self.frames:
            return None
        n, first, last = scene_frame + offset, self.first, self.last
        if n < first or n > last:
            if mode == "CLIP":
                return None
            if mode == "REPEAT":
                n = first + (n - first) % (last - first + 1)
            elif mode == "PING_PONG" and last > first:
                period = 2 * (last - first)
                t = (n - first) % period
                n = first + (t if t <= last - first else period - t)
            else:
                n = min(max(n, first), last)
        return _at_or_before(self.frames, n)


def _at_or_before(frames, n):
    import bisect
    i = bisect.bisect_right(frames, n)
    return frames[i - 1] if i else frames[0]


def parse_pattern(path):
    """The Sequence (frames not scanned) of a path with '#' or %0Nd in its file name, else None.
    @raise SequenceError for a placeholder in a folder name."""
    directory, filename = os.path.split(path)
    if _PLACEHOLDER.search(directory) and not _PLACEHOLDER.search(filename):
        raise SequenceError(f"{path!r}: the frame number must be in the file name, not a folder")
    found = list(_PLACEHOLDER.finditer(filename))
    if not found:
        return None
    m = found[-1]
    width = len(m.group(1)) if m.group(1) else int(m.group(3) or 1)
    return Sequence(directory, filename[:m.start()], filename[m.end():], max(width, 1))


def detect(path):
    """The sequence that file `path` belongs to (or that the pattern `path` names), frames
    scanned. The padding is the file's digit count when its siblings agree, else 1 (unpadded).
    @raise SequenceError without a frame number or without any frame on disk."""
    pattern = parse_pattern(path)
    if pattern is not None:
        pattern.scan()
        if not pattern.frames:
            raise SequenceError(f"no file matches {path!r}")
        return pattern
    directory, filename = os.path.split(path)
    stem, ext = os.path.splitext(filename)
    m = _LAST_DIGITS.search(stem)
    if m is None:
        raise SequenceError(f"{filename!r} has no frame number: a sequence is name.0001.ply, "
                            "name.0002.ply, ...")
    prefix, suffix = stem[:m.start()], stem[m.end():] + ext
    width = len(m.group(1))
    candidates = [Sequence(directory, prefix, suffix, w).scan() for w in sorted({width, 1})]
    best = max(candidates, key=lambda s: (len(s.frames), s.width))
    if best.matches(filename) is None:       # the given file must belong to what is chosen
        best = candidates[-1] if candidates[-1].matches(filename) is not None else candidates[0]
    if not best.frames:
        raise SequenceError(f"no file of the sequence {best.pattern!r} on disk")
    return best


def pattern_of(path):
    """The '#' pattern of one numbered file (e.g. a Blender volume's filepath): the last digit
    run of its name becomes as many '#'. @raise SequenceError without digits."""
    directory, filename = os.path.split(path)
    stem, ext = os.path.splitext(filename)
    m = _LAST_DIGITS.search(stem)
    if m is None:
        raise SequenceError(f"{filename!r} has no frame number")
    return os.path.join(directory, stem[:m.start()] + "#" * len(m.group(1)) + stem[m.end():] + ext)


def frame_of(path):
    """The number in the last digit run of the file name of `path`, or None."""
    stem = os.path.splitext(os.path.basename(path))[0]
    m = _LAST_DIGITS.search(stem)
    return int(m.group(1)) if m else None


def object_name(sequence):
    """A readable name: the prefix without trailing separators ("smoke." -> "smoke")."""
    return sequence.prefix.rstrip("._- ") or os.path.splitext(sequence.suffix)[0].strip("._- ") \
        or "sequence"


# --- the cache of parsed frames ---------------------------------------------------------------

class FrameCache:
    """A bounded LRU cache of parsed frames: key (path, size, mtime) -> value, at most
    `capacity` entries. A file rewritten on disk is a new key, so it is read again."""

    def __init__(self, capacity=8):
        self.capacity = capacity
        self._items = OrderedDict()
        self.hits = self.misses = 0

    @staticmethod
    def key(path):
        st = os.stat(path)
        return (os.path.abspath(path), st.st_size, st.st_mtime_ns)

    def get(self, path, load):
        """The value of `path`, from the cache or `load(path)` (then cached)."""
        key = self.key(path)
        if key in self._items:
            self._items.move_to_end(key)
            self.hits += 1
            return self._items[key]
        self.misses += 1
        value = load(path)
        self._items[key] = value
        while len(self._items) > self.capacity:
            self._items.popitem(last=False)
        return value

    def __len__(self):
        return len(self._items)

    def paths(self):
        return [k[0] for k in self._items]

    def clear(self):
        self._items.clear()
        self.hits = self.misses = 0


# --- the sequence summary and the range of a measure over every frame ---------------------------

def _same_pattern(a, b):
    """Two patterns name the same files ('####' and '%04d' alike)."""
    pa, pb = parse_pattern(a), parse_pattern(b)
    return pa is not None and pb is not None and \
        (os.path.basename(pa.pattern) == os.path.basename(pb.pattern))


def find_summary(sequence, paths=None):
    """(path, document) of the sequence summary JSON (`isouq mesh ... --summary`, SPEC §10) in
    the sequence's folder that describes these files (its `sequence.output` or
    `sequence.hidden_output` pattern, or a frame's `output`), else (None, None)."""
    folder = sequence.directory or "."
    if paths is None:
        try:
            paths = sorted(os.path.join(folder, n) for n in os.listdir(folder)
                           if n.endswith(".json"))[:MAX_SUMMARY_FILES]
        except OSError:
            return None, None
    ours = {os.path.basename(sequence.path(f)) for f in sequence.frames}
    for path in paths:
        doc = read_summary(path)
        if doc is None:
            continue
        seq = doc.get("sequence") or {}
        outputs = [seq.get(k) for k in ("output", "hidden_output") if isinstance(seq.get(k), str)]
        if any(_same_pattern(o, sequence.pattern) for o in outputs):
            return path, doc
        if any(isinstance(e.get("output"), str) and os.path.basename(e["output"]) in ours
               for e in doc["frames"] if isinstance(e, dict)):
            return path, doc
    return None, None


def read_summary(path):
    """The JSON document at `path` if it is a sequence summary (a `frames` list), else None."""
    try:
        if os.path.getsize(path) > MAX_SUMMARY_BYTES:
            return None
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        return None
    return doc


def frame_entries(doc):
    """{frame number: that frame's summary entry} of a sequence summary."""
    out = {}
    for e in doc.get("frames", ()):
        if isinstance(e, dict) and isinstance(e.get("frame"), int):
            out[e["frame"]] = e
    return out


def frame_summary(doc, frame):
    """The frame's entry with the run's isovalue and method (what C7 shows for one frame)."""
    entry = frame_entries(doc).get(frame)
    if entry is None:
        return None
    merged = {k: doc[k] for k in ("isovalue", "isovalue_source", "method") if k in doc}
    merged.update(entry)
    return merged


def _finite(x):
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def summary_ranges(doc):
    """{measure: (min, max)} over every frame of a sequence summary: each measure's `min` and
    `max` objects per frame (frames with no vertices do not count)."""
    lo, hi = {}, {}
    for e in frame_entries(doc).values():
        for name, st in e.items():
            if not isinstance(st, dict) or not (_finite(st.get("min")) and _finite(st.get("max"))):
                continue
            if st.get("count", 1) == 0:
                continue
            lo[name] = min(lo.get(name, math.inf), float(st["min"]))
            hi[name] = max(hi.get(name, -math.inf), float(st["max"]))
    return {name: (lo[name], hi[name]) for name in lo}


def scan_ranges(paths, read):
    """{column: (min, max)} of the finite values of every float vertex column over the meshes
    `read(path)` (an IsouqMesh) of `paths`: each frame read once."""
    import numpy as np
    lo, hi = {}, {}
    for path in paths:
        mesh = read(path)
        for name, column in mesh.vertex_attributes.items():
            if column.dtype.kind != "f":
                continue
            v = column[np.isfinite(column)]
            if len(v):
                lo[name] = min(lo.get(name, math.inf), float(v.min()))
                hi[name] = max(hi.get(name, -math.inf), float(v.max()))
    return {name: (lo[name], hi[name]) for name in lo}
