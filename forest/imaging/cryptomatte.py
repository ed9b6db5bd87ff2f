"""Cryptomatte: per-object coverage mattes a compositor can pick by name.

Implements the Cryptomatte specification (Friedman & Jones, Psyop, “Fully
Automatic ID Mattes with Support for Motion Blur and Transparency”, SIGGRAPH
2015 poster; specification v1.2.0):

- **ID**: the 32-bit MurmurHash3 (x86_32, seed 0; Appleby, SMHasher) of the
  object's UTF-8 name, reinterpreted as a float32 after the
  ``uint32_to_float32`` conversion: an exponent of 0 (denormals, zero) or 255
  (inf, NaN) has its lowest bit flipped, so every ID is a normal finite float.
- **Ranking filter**: every sample of a pixel carries an ID and a weight
  (pixel-filter weight × opacity).  Per pixel and ID the weights are summed and
  divided by the pixel's total weight, samples that hit nothing included, so
  ``coverage`` of an object is the fraction of the pixel it covers.  IDs are
  ranked by coverage (ties: the smaller integer ID first, for determinism).
- **Layers**: ``{type}00`` … ``{type}NN``, RGBA each: ``R`` = ID of rank 2k,
  ``G`` = its coverage, ``B`` = ID of rank 2k+1, ``A`` = its coverage; empty
  ranks hold 0.  Six ranks (three layers) is the spec's default.
- **Header**: ``cryptomatte/<key>/name`` (the type name), ``…/hash`` =
  ``MurmurHash3_32``, ``…/conversion`` = ``uint32_to_float32`` and
  ``…/manifest``, a JSON object ``{name: "%08x" of the float ID's bits}`` of the
  names that appear in the frame; ``<key>`` is the first 7 hex digits of the
  MurmurHash3 of the type name.

A renderer feeds it per-sample IDs as integers with an integer → name table,
either all samples of a pixel at once (:func:`rank_coverage`) or pass by pass
(:class:`CoverageAccumulator`), then :func:`encode` turns the ranking into
channels and header attributes for :func:`forest.imaging.exr.write_comp_exr`.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

HASH = "MurmurHash3_32"
CONVERSION = "uint32_to_float32"
DEFAULT_RANKS = 6
NONE = -1
"""The sample ID of a sample that hit nothing (sky, background)."""
TREE_MATTE = "CryptoObject"
"""Type name of the per-tree Cryptomatte (names ``<species>/<tree id>``)."""
SPECIES_MATTE = "CryptoAsset"
"""Type name of the per-species Cryptomatte (a species is the library asset a tree instances)."""

_C1, _C2 = np.uint32(0xCC9E2D51), np.uint32(0x1B873593)
_M1, _M2 = np.uint32(0x85EBCA6B), np.uint32(0xC2B2AE35)


def _rotl(x: np.ndarray, r: int) -> np.ndarray:
    return (x << np.uint32(r)) | (x >> np.uint32(32 - r))


def murmurhash3_32(names: Sequence[str] | str, seed: int = 0) -> np.ndarray:
    """MurmurHash3_x86_32 of each name's UTF-8 bytes, as ``uint32`` (vectorised over names of equal length).

    Austin Appleby's algorithm (SMHasher, public domain): 4-byte little-endian
    blocks ``k`` mixed as ``k·c1, rotl 15, ·c2``, folded into ``h`` with
    ``rotl 13, ·5 + 0xe6546b64``; the tail bytes likewise; then ``h ^= len`` and
    the ``fmix32`` finaliser.  A single string gives a 0-d array.
    """
    single = isinstance(names, str)
    items: Sequence[str] = [names] if isinstance(names, str) else names
    encoded = [n.encode("utf-8") for n in items]
    out = np.empty(len(encoded), dtype=np.uint32)
    lengths = np.array([len(b) for b in encoded], dtype=np.int64)
    with np.errstate(over="ignore"):
        for n in np.unique(lengths):
            idx = np.flatnonzero(lengths == n)
            raw = np.frombuffer(b"".join(encoded[i] for i in idx), dtype=np.uint8).reshape(len(idx), int(n))
            h = np.full(len(idx), seed, dtype=np.uint32)
            nblocks = int(n) // 4
            if nblocks:
                blocks = np.ascontiguousarray(raw[:, : nblocks * 4]).view("<u4").astype(np.uint32)
                for b in range(nblocks):
                    k = blocks[:, b] * _C1
                    k = _rotl(k, 15) * _C2
                    h = _rotl(h ^ k, 13) * np.uint32(5) + np.uint32(0xE6546B64)
            tail = raw[:, nblocks * 4 :].astype(np.uint32)
            if tail.shape[1]:
                k = np.zeros(len(idx), dtype=np.uint32)
                for j in range(tail.shape[1]):
                    k |= tail[:, j] << np.uint32(8 * j)
                h ^= _rotl(k * _C1, 15) * _C2
            h ^= np.uint32(n & 0xFFFFFFFF)
            h ^= h >> np.uint32(16)
            h *= _M1
            h ^= h >> np.uint32(13)
            h *= _M2
            h ^= h >> np.uint32(16)
            out[idx] = h
    return out[0] if single else out


def hash_to_float(h: np.ndarray) -> np.ndarray:
    """``uint32_to_float32``: flip the lowest exponent bit of exponent 0 or 255, reinterpret as float32."""
    h = np.asarray(h, dtype=np.uint32)
    exponent = (h >> np.uint32(23)) & np.uint32(0xFF)
    fixed = np.where((exponent == 0) | (exponent == 255), h ^ np.uint32(1 << 23), h).astype(np.uint32)
    return fixed.view(np.float32)


def name_ids(names: Sequence[str]) -> np.ndarray:
    """The Cryptomatte float32 ID of each name."""
    return hash_to_float(murmurhash3_32(list(names)))


def id_hex(ids: np.ndarray) -> list[str]:
    """Manifest spelling of float IDs: 8 lower-case hex digits of their bits."""
    return [f"{int(b):08x}" for b in np.asarray(ids, dtype=np.float32).view(np.uint32).ravel()]


def layer_key(type_name: str) -> str:
    """The metadata key of a Cryptomatte type: 7 hex digits of the MurmurHash3 of its name."""
    return f"{int(murmurhash3_32(type_name)):08x}"[:7]


# ------------------------------------------------------------------ ranking filter


@dataclass(frozen=True)
class Ranking:
    """Per-pixel IDs by coverage: ``ids (H, W, R)`` signed ints (:data:`NONE` where empty), ``coverage (H, W, R)``."""

    ids: np.ndarray
    coverage: np.ndarray


def _as_samples(ids: np.ndarray, weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Sample IDs as a signed (H, W, S) array and weights alike as float64 (None: all samples weigh 1)."""
    ids = np.asarray(ids)
    if ids.ndim == 2:
        ids = ids[..., None]
    if ids.ndim != 3 or ids.dtype.kind not in "iu":
        raise ValueError(f"sample ids must be an integer (H, W) or (H, W, S) array, got {ids.dtype} {ids.shape}")
    if ids.dtype.kind == "u" or ids.dtype.itemsize < 4:
        ids = ids.astype(np.int64)
    if weights is None:
        return ids, None
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim == 2:
        w = w[..., None]
    if w.shape != ids.shape:
        raise ValueError(f"weights {w.shape} must match sample ids {ids.shape}")
    if not np.isfinite(w).all() or (w < 0).any():
        raise ValueError("sample weights must be finite and non-negative")
    return ids, w


def _top(ids: np.ndarray, w: np.ndarray | None, keep: int) -> tuple[np.ndarray, np.ndarray]:
    """Sum equal IDs along the last axis and keep the ``keep`` largest sums (ties: smaller ID first).

    ``ids``/``w`` are (P, S) (``w`` None: every sample weighs 1); :data:`NONE`
    entries are dropped.  Sorting each row by ID makes equal IDs runs; a run's
    sum is the cumulative weight at its last sample minus that just before its
    first.  Returns (P, keep) IDs (NONE-padded) and their sums (0-padded).
    """
    p, s = ids.shape
    if w is None:
        sid = np.sort(ids, axis=1)
        csum = np.broadcast_to(np.arange(1.0, s + 1.0), (p, s))
    else:
        order = np.argsort(ids, axis=1, kind="stable")
        sid = np.take_along_axis(ids, order, axis=1)
        csum = np.cumsum(np.take_along_axis(w, order, axis=1), axis=1)
    change = sid[:, 1:] != sid[:, :-1]
    last = np.ones((p, s), dtype=bool)
    last[:, :-1] = change
    start_idx = np.zeros((p, s), dtype=np.intp)
    start_idx[:, 1:] = np.where(change, np.arange(1, s)[None, :], 0)
    np.maximum.accumulate(start_idx, axis=1, out=start_idx)  # index of each run's first sample
    if w is None:
        start = start_idx.astype(np.float64)
    else:
        before = np.zeros((p, s))
        before[:, 1:] = csum[:, :-1]
        start = np.take_along_axis(before, start_idx, axis=1)
    run = np.where(last & (sid != NONE), csum - start, -1.0)
    rank = np.argsort(-run, axis=1, kind="stable")[:, :keep]  # ids ascending already: ties keep the smaller id
    top_w = np.take_along_axis(run, rank, axis=1)
    top_id = np.take_along_axis(sid, rank, axis=1)
    empty = top_w <= 0.0
    top_id = np.where(empty, NONE, top_id)
    top_w = np.where(empty, 0.0, top_w)
    if top_id.shape[1] < keep:
        pad = keep - top_id.shape[1]
        top_id = np.pad(top_id, ((0, 0), (0, pad)), constant_values=NONE)
        top_w = np.pad(top_w, ((0, 0), (0, pad)))
    return top_id, top_w


class CoverageAccumulator:
    """Accumulates weighted ID samples pass by pass into per-pixel coverage.

    Keeps, per pixel, the ``keep`` IDs with the most weight so far plus the
    total weight of every sample (hits and misses).  Exact as long as a pixel
    sees at most ``keep`` distinct IDs; beyond that the smallest contributors
    of a pass can be dropped (the ranks written are ≤ ``keep``, so choose
    ``keep`` ≥ 2 × ranks).  Memory: ``H·W·keep·16`` bytes.
    """

    def __init__(self, height: int, width: int, *, keep: int = 2 * DEFAULT_RANKS, rows_per_chunk: int = 64):
        self.height, self.width, self.keep = int(height), int(width), int(keep)
        self.rows_per_chunk = int(rows_per_chunk)
        self.ids = np.full((self.height, self.width, self.keep), NONE, dtype=np.int64)
        self.weight = np.zeros((self.height, self.width, self.keep), dtype=np.float64)
        self.total = np.zeros((self.height, self.width), dtype=np.float64)

    def add(self, ids: np.ndarray, weights: np.ndarray | None = None) -> None:
        """Add samples: ``ids (H, W[, S])`` integers (:data:`NONE` = nothing hit), ``weights`` alike (default 1)."""
        ids, w = _as_samples(ids, weights)
        if ids.shape[:2] != (self.height, self.width):
            raise ValueError(f"samples are {ids.shape[:2]}, the accumulator is {(self.height, self.width)}")
        if w is None:
            w = np.ones(ids.shape, dtype=np.float64)
        self.total += w.sum(axis=2)
        for r0 in range(0, self.height, self.rows_per_chunk):
            r1 = min(self.height, r0 + self.rows_per_chunk)
            cat_id = np.concatenate([self.ids[r0:r1], ids[r0:r1]], axis=2).reshape(-1, self.keep + ids.shape[2])
            cat_w = np.concatenate([self.weight[r0:r1], w[r0:r1]], axis=2).reshape(cat_id.shape)
            top_id, top_w = _top(cat_id, cat_w, self.keep)
            self.ids[r0:r1] = top_id.reshape(r1 - r0, self.width, self.keep)
            self.weight[r0:r1] = top_w.reshape(r1 - r0, self.width, self.keep)

    def ranking(self, ranks: int = DEFAULT_RANKS) -> Ranking:
        """The top ``ranks`` IDs per pixel with coverage = weight / the pixel's total weight."""
        total = np.where(self.total > 0, self.total, 1.0)[..., None]
        cov = (self.weight[..., :ranks] / total).astype(np.float32)
        ids = self.ids[..., :ranks]
        if ranks > self.keep:
            pad = ranks - self.keep
            ids = np.pad(ids, ((0, 0), (0, 0), (0, pad)), constant_values=NONE)
            cov = np.pad(cov, ((0, 0), (0, 0), (0, pad)))
        return Ranking(ids=ids.copy(), coverage=cov)


def rank_coverage(
    ids: np.ndarray, weights: np.ndarray | None = None, *, ranks: int = DEFAULT_RANKS, rows_per_chunk: int = 64
) -> Ranking:
    """The ranking filter over all samples at once: ``ids (H, W[, S])``, ``weights`` alike (default 1).

    Also takes per-pixel lists that are already summed (IDs with their coverage
    as weights): equal IDs are merged either way.  Works on ``rows_per_chunk``
    image rows at a time (memory ≈ rows·W·S·40 bytes).
    """
    ids, w = _as_samples(ids, weights)
    h, width, s = ids.shape
    total = np.full((h, width), float(s)) if w is None else w.sum(axis=2)
    out_ids = np.full((h, width, ranks), NONE, dtype=ids.dtype)
    out_cov = np.zeros((h, width, ranks), dtype=np.float32)
    if s == 1:  # one sample per pixel (a pixel-centre id pass): the id covers the pixel
        hit = ids[..., 0] != NONE
        if w is not None:
            hit &= w[..., 0] > 0
        if ranks:
            out_ids[..., 0] = np.where(hit, ids[..., 0], NONE)
            out_cov[..., 0] = hit
        return Ranking(ids=out_ids, coverage=out_cov)
    for r0 in range(0, h, rows_per_chunk):
        r1 = min(h, r0 + rows_per_chunk)
        chunk_w = None if w is None else w[r0:r1].reshape(-1, s)
        top_id, top_w = _top(ids[r0:r1].reshape(-1, s), chunk_w, ranks)
        norm = np.where(total[r0:r1] > 0, total[r0:r1], 1.0).reshape(-1, 1)
        out_ids[r0:r1] = top_id.reshape(r1 - r0, width, ranks)
        out_cov[r0:r1] = (top_w / norm).reshape(r1 - r0, width, ranks)
    return Ranking(ids=out_ids, coverage=out_cov)


# ------------------------------------------------------------------ encoding


Names = Sequence[str] | Mapping[int, str] | Callable[[np.ndarray], Sequence[str]]
"""An ID → name table: a sequence indexed by ID, a mapping, or a function of an array of IDs."""


def _lookup(names: Names, ids: np.ndarray) -> list[str]:
    out = list(names(ids)) if callable(names) else [names[int(i)] for i in ids]
    if len(out) != len(ids):
        raise ValueError("the name table returned a different number of names than IDs")
    return [str(n) for n in out]


@dataclass(frozen=True)
class Cryptomatte:
    """One Cryptomatte type ready to write: its channels and header attributes."""

    type_name: str
    channels: dict[str, np.ndarray]
    attributes: dict[str, str]
    manifest: dict[str, str]


def encode(type_name: str, ranking: Ranking, names: Names) -> Cryptomatte:
    """Turn a :class:`Ranking` into ``{type}NN.RGBA`` float32 channels and the ``cryptomatte/…`` header.

    Only the IDs that appear in the frame are hashed and listed in the manifest.
    """
    if not type_name or any(c in type_name for c in "./ "):
        raise ValueError(f"bad Cryptomatte type name {type_name!r}")
    ids = ranking.ids
    present = np.unique(ids[ids != NONE])
    labels = _lookup(names, present)
    float_ids = name_ids(labels) if labels else np.zeros(0, np.float32)
    valid = ids != NONE
    values = np.zeros(ids.shape, dtype=np.float32)
    if present.size:
        values[valid] = float_ids[np.searchsorted(present, ids[valid])]
    cov = np.where(valid, ranking.coverage, 0.0).astype(np.float32)
    ranks = ids.shape[2]
    channels: dict[str, np.ndarray] = {}
    for layer in range((ranks + 1) // 2):
        prefix = f"{type_name}{layer:02d}"
        for c, (plane, k) in zip("RGBA", ((values, 0), (cov, 0), (values, 1), (cov, 1))):
            r = 2 * layer + k
            channels[f"{prefix}.{c}"] = plane[..., r] if r < ranks else np.zeros(ids.shape[:2], np.float32)
    manifest = dict(sorted(zip(labels, id_hex(float_ids))))
    key = layer_key(type_name)
    attributes = {
        f"cryptomatte/{key}/name": type_name,
        f"cryptomatte/{key}/hash": HASH,
        f"cryptomatte/{key}/conversion": CONVERSION,
        f"cryptomatte/{key}/manifest": json.dumps(manifest, separators=(",", ":"), ensure_ascii=False),
    }
    return Cryptomatte(type_name=type_name, channels=channels, attributes=attributes, manifest=manifest)


# ------------------------------------------------------------------ decoding (what a compositor does)


def find_type(attributes: Mapping[str, object], type_name: str) -> tuple[str, dict[str, str]]:
    """The key and the manifest of Cryptomatte type ``type_name`` in an EXR header."""
    for k, v in attributes.items():
        if k.startswith("cryptomatte/") and k.endswith("/name") and v == type_name:
            key = k.split("/")[1]
            manifest = json.loads(str(attributes.get(f"cryptomatte/{key}/manifest", "{}")))
            return key, manifest
    raise KeyError(f"no Cryptomatte type {type_name!r} in the header")


def extract_matte(channels: Mapping[str, np.ndarray], type_name: str, names: Sequence[str]) -> np.ndarray:
    """The matte of ``names`` in type ``type_name``: the summed coverage of every rank whose ID is theirs.

    ``channels`` as :func:`forest.images.read_exr_channels` returns them.  The
    IDs are computed from the names (the manifest is not needed).
    """
    wanted = name_ids(list(names))
    matte: np.ndarray | None = None
    layer = 0
    while f"{type_name}{layer:02d}.R" in channels:
        prefix = f"{type_name}{layer:02d}"
        for id_c, cov_c in (("R", "G"), ("B", "A")):
            ids = np.asarray(channels[f"{prefix}.{id_c}"], dtype=np.float32)
            cov = np.asarray(channels[f"{prefix}.{cov_c}"], dtype=np.float32)
            hit = np.isin(ids.view(np.uint32), wanted.view(np.uint32)) & (cov > 0)
            part = np.where(hit, cov, 0.0)
            matte = part if matte is None else matte + part
        layer += 1
    if matte is None:
        raise KeyError(f"no {type_name}00 layer")
    return matte.astype(np.float32)


# ------------------------------------------------------------------ forest's two mattes: trees and species


class TreeTable:
    """Tree id → species lookups for a frame's instances (InstanceSet ``id`` and ``species`` columns).

    Sample IDs follow one convention: ≥ 0 a tree id, :data:`NONE` (−1) nothing
    hit, ≤ −2 another named object listed in ``others`` (e.g. ``{-2: "terrain"}``).
    """

    def __init__(
        self,
        tree_ids: np.ndarray,
        tree_species: np.ndarray,
        species_names: Sequence[str],
        others: Mapping[int, str] | None = None,
    ):
        ids = np.asarray(tree_ids, dtype=np.int64)
        order = np.argsort(ids, kind="stable")
        self.sorted_ids = ids[order]
        self.sorted_species = np.asarray(tree_species, dtype=np.int64)[order]
        self.species_names = [str(s) for s in species_names]
        self.others = {int(k): str(v) for k, v in (others or {}).items()}
        if any(k >= NONE for k in self.others):
            raise ValueError("other objects need sample IDs ≤ -2")

    def species_of(self, sample_ids: np.ndarray) -> np.ndarray:
        """Sample tree ids → species indices (other objects and NONE keep their negative IDs)."""
        s = np.asarray(sample_ids, dtype=np.int64)
        tree = s >= 0
        pos = np.clip(np.searchsorted(self.sorted_ids, s[tree]), 0, max(len(self.sorted_ids) - 1, 0))
        if tree.any() and not np.array_equal(self.sorted_ids[pos], s[tree]):
            raise ValueError("a sample names a tree id that is not in the table")
        out = s.copy()
        out[tree] = self.sorted_species[pos]
        return out

    def tree_names(self, ids: np.ndarray) -> list[str]:
        """Matte names of tree / object IDs: ``<species>/<tree id>``, or the other object's name."""
        ids = np.asarray(ids, dtype=np.int64)
        species = self.species_of(ids)
        return [
            f"{self.species_names[int(sp)]}/{int(i)}" if i >= 0 else self.others[int(i)] for i, sp in zip(ids, species)
        ]

    def species_label(self, ids: np.ndarray) -> list[str]:
        """Matte names of species indices (and other objects)."""
        return [self.species_names[int(i)] if i >= 0 else self.others[int(i)] for i in np.asarray(ids)]


def forest_mattes(
    sample_ids: np.ndarray,
    weights: np.ndarray | None,
    table: TreeTable,
    *,
    ranks: int = DEFAULT_RANKS,
    tree_type: str = TREE_MATTE,
    species_type: str = SPECIES_MATTE,
) -> tuple[Cryptomatte, Cryptomatte]:
    """Per-tree and per-species Cryptomattes from per-sample IDs ``(H, W[, S])`` and weights."""
    trees = encode(tree_type, rank_coverage(sample_ids, weights, ranks=ranks), table.tree_names)
    species_ids = table.species_of(np.asarray(sample_ids))
    species = encode(species_type, rank_coverage(species_ids, weights, ranks=ranks), table.species_label)
    return trees, species
