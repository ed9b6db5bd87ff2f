"""Job requests: the request schema, service limits, and splitting a job into tasks.

A request is checked in this order, each failure answering a 4xx with one line that
names the field: the JSON schema (pydantic), the config's TOML syntax, every asset path
in the config (inside the data folder, see :mod:`forest.service.assets`), the config's own
validation (``forest.config``), the service's limits on resolution, samples, candidates
and frames, then what the CLI checks before it starts work (:func:`_check_inputs`: the
species against the library and how many tree variants it would generate, the environment
map and terrain texture; a render's image against the memory its workers have room for,
:func:`_check_memory`; a match job's reference at the fit's size).  Only then is the job
stored, so a bad request leaves nothing.  The words are the CLI's: a malformed request's first problem is worded as the
config's (:func:`validation_line`), an upload is decoded by the CLI's image reader, and
files are named as the request names them, never by their place in the job folder.
A limit is named by the setting that gave the value (``settings.width``) or else by the
config's field (``config: render.width``).

A library error about a parameter (:class:`forest.errors.ParameterError`) is answered
with the request's JSON field for it (:func:`forest.service.views.field_name`).

Tasks: a fly-through of N frames is N tasks by default (``frames_per_task`` groups
them); a still, a match and an export are one task each.  Every task's
:class:`~forest.service.models.TaskSpec` carries the config text, the overrides and the
SHA-256 of each input file, so any worker can fetch and cache them.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from forest.config import MAX_CONFIG_BYTES
from forest.errors import ConfigError

from .assets import AssetError, DataDir, asset_kind, collect_assets, link_into
from .models import Kind, MatchSpec, Resources, TaskSpec, Variant
from .transfer import file_sha256
from .views import field_name


@dataclass(frozen=True)
class Limits:
    """What one job may ask for.  Over a limit ⇒ 422 naming the setting."""

    max_width: int = 4096
    max_height: int = 4096
    max_pixels: int = 4096 * 2160
    max_spp: int = 1024
    max_trees: int = 2_000_000
    max_frames: int = 2000
    max_upload_bytes: int = 64 * 2**20
    max_decoded_bytes: int = 512 * 2**20  # an uploaded image decoded (float32), checked from its header first
    max_config_bytes: int = MAX_CONFIG_BYTES  # the CLI's limit too
    max_iterations: int = 2000
    #: Refuse at submission a render whose image alone needs more memory than the workers have room for.
    check_memory: bool = True
    #: The room (bytes) a render task has; None: this machine's (``forest.preflight.memory_room``: available
    #: memory and cgroup limits, read at each submission), where the local workers run.  A worker checks the
    #: render again once its trees are known, against the smaller of this and its own room.
    worker_memory_bytes: int | None = None


class JobSettings(BaseModel):
    """Per-job settings; each overrides the matching key of the config.

    Strict, as the config is: ``"width": "64"`` is refused (a string is not a number).
    """

    model_config = ConfigDict(extra="forbid", strict=True)
    width: int | None = Field(default=None, ge=1, le=16384, description="Image width in pixels ([render] width).")
    height: int | None = Field(default=None, ge=1, le=16384, description="Image height in pixels ([render] height).")
    spp: int | None = Field(default=None, ge=1, le=65536, description="Samples per pixel ([render] spp).")
    variant: Variant | None = Field(default=None, description="Mitsuba variant; default: the renderer's choice.")
    seed: int | None = Field(default=None, ge=0, le=2**63 - 1, description="Scene seed (top-level seed).")
    count: int | None = Field(default=None, ge=0, le=20_000_000, description="Candidate sites ([scatter] count).")
    frames: str | None = Field(
        default=None,
        max_length=200,
        pattern=r"^[0-9xX,\- ]+$",
        description="Fly-through (or export) frames, e.g. '1-24' or '1-120x2'; default: the camera keys' range.",
    )
    frames_per_task: int | None = Field(
        default=None, ge=1, le=10000, description="Frames per fly-through task (default 1)."
    )
    cpus: float | None = Field(default=None, gt=0, le=1024, description="CPUs to reserve per task (Ray executor).")
    gpus: float | None = Field(
        default=None,
        ge=0,
        le=64,
        description="GPUs to reserve per task (Ray executor); default 1 for cuda_ad_rgb, else 0. A task that names "
        "no variant uses a reserved GPU where it passed forest's self-check.",
    )
    preview: bool = Field(default=False, description="Fast low-quality preview render.")
    quick_look: bool = Field(default=True, description="Stills: show a small one-sample image before the first pass.")
    reference: str | None = Field(
        default=None, max_length=512, description="Match jobs: reference photo (an asset name)."
    )
    mask: str | None = Field(
        default=None,
        max_length=512,
        description="Match jobs: regions painted over the reference (an asset name; lookdev.mask): sky #0000ff, "
        "canopy #00ff00, ground #ff0000, ignored #000000, automatic #ffffff.",
    )
    iterations: int | None = Field(default=None, ge=1, le=100000, description="Match jobs: optimisation steps.")
    resolution: int | None = Field(
        default=None, ge=8, le=4096, description="Match jobs: fit render long side in pixels."
    )
    match_spp: int | None = Field(default=None, ge=1, le=1024, description="Match jobs: samples per pixel per step.")
    params: list[str] | None = Field(default=None, max_length=32, description="Match jobs: which parameters to fit.")
    mode: str | None = Field(
        default=None, max_length=64, pattern=r"^[A-Za-z0-9_-]+$", description="Match jobs: fit mode."
    )
    renderman22: bool = Field(default=False, description="RIB jobs: RenderMan 22+ style (Procedural2, Pxr lights).")


class JobRequest(BaseModel):
    """``POST /jobs`` body."""

    model_config = ConfigDict(extra="forbid", strict=True)
    kind: Kind = Field(..., description="render (a still), flythrough, match, rib or usd (exports).")
    config: str = Field(..., min_length=1, description="The scene config as TOML text (at most 1 MiB).")
    settings: JobSettings = Field(default_factory=lambda: JobSettings())
    priority: int = Field(0, ge=-100, le=100, description="Higher runs first.")
    name: str | None = Field(default=None, max_length=200, description="Default: the config's `name`.")


class RequestError(Exception):
    """A job request the service refuses: one line for ``detail`` and the HTTP ``status`` (422 by default)."""

    def __init__(self, message: str, status: int = 422):
        super().__init__(message)
        self.status = status


class _Errors:
    """Pydantic's error list in the shape :func:`forest.config.messages.first_error` reads."""

    def __init__(self, errors: list[dict[str, Any]]):
        self._errors = errors

    def errors(self, include_url: bool = False) -> list[dict[str, Any]]:  # noqa: ARG002 (ValidationError.errors)
        return self._errors


def validation_line(errors: list[dict[str, Any]], body: Any = None) -> str:
    """A request's first validation error as one line, in the config's words: ``settings.spp: must be >= 1, got 0``.

    The wording is :func:`forest.config.messages.first_error`'s — the words the CLI uses
    for the same value in a config — with the request's JSON field (``body`` dropped from
    the location; a query or header parameter keeps its place: ``query.limit``).
    """
    from forest.config.messages import dotted, first_error

    if not errors:
        return "invalid request"
    e = dict(errors[0])
    if "input" in e:
        e["input"] = _short(e["input"])
    loc = tuple(e.get("loc") or ())
    if loc[:1] == ("body",):
        loc = loc[1:]
        data = body
    else:
        data = None
    e["loc"] = loc
    if e.get("type") == "extra_forbidden":
        model: type[BaseModel] = JobSettings if loc[:1] == ("settings",) else JobRequest
        return f"{dotted(loc)}: unknown key (expected one of: {', '.join(sorted(model.model_fields))})"
    if e.get("type") == "json_invalid":
        return f"body: invalid JSON: {(e.get('ctx') or {}).get('error', e.get('msg', ''))}"
    if e.get("type") == "string_pattern_mismatch":
        return f"{dotted(loc)}: {_pattern_words(loc)}, got {e.get('input')!r}"
    field, message = first_error(_Errors([e]), data)  # type: ignore[arg-type]
    return f"{field}: {message}" if field else message


#: Longest value a validation message quotes back; a longer one is described, never echoed.
ECHO_CHARS = 80


class _Described:
    """A value too long to quote in a message: its ``repr`` is a description (a 5,000-character string)."""

    def __init__(self, text: str):
        self.text = text

    def __repr__(self) -> str:
        return self.text


def _short(value: Any) -> Any:
    """``value`` itself when its ``repr`` is short, else a :class:`_Described` of its type and size."""
    text = repr(value)
    if len(text) <= ECHO_CHARS:
        return value
    if isinstance(value, (str, bytes, bytearray)):
        return _Described(f"a {len(value):,}-character {'string' if isinstance(value, str) else 'byte string'}")
    if isinstance(value, (list, tuple, dict)):
        kind = "table" if isinstance(value, dict) else "list"
        return _Described(f"a {kind} of {len(value):,} item{'s' if len(value) != 1 else ''}")
    return _Described(f"a {type(value).__name__} value ({len(text):,} characters)")


def _pattern_words(loc: tuple[Any, ...]) -> str:
    if loc == ("settings", "frames"):
        return "must be frames such as '1-24', '1-120x2' or '1,5,9'"
    if loc == ("settings", "mode"):
        return "must be a word of letters, digits, '-' or '_'"
    return "has characters it may not hold"


def request_hash(req: JobRequest) -> str:
    """SHA-256 of the request's canonical JSON: what an ``Idempotency-Key`` is checked against."""
    return hashlib.sha256(json.dumps(req.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()


@dataclass
class PreparedJob:
    """A checked request ready for the store: the job's id, folder, name, settings and task specs."""

    job_id: str
    job_dir: Path
    name: str | None
    settings: dict
    task_specs: list[TaskSpec]


OVERRIDES = (
    ("width", "render.width"),
    ("height", "render.height"),
    ("spp", "render.spp"),
    ("seed", "seed"),
    ("count", "scatter.count"),
    ("variant", "render.variant"),
    ("mask", "lookdev.mask"),
)


def _overrides(s: JobSettings, data: dict) -> dict[str, Any]:
    """The config keys the settings set (refusing a setting whose table is not a table)."""
    out: dict[str, Any] = {}
    for key, dotted in OVERRIDES:
        value = getattr(s, key)
        if value is None:
            continue
        *parents, _ = dotted.split(".")
        node: Any = data
        for part in parents:
            node = node.get(part, {}) if isinstance(node, dict) else None
            if not isinstance(node, dict):
                raise RequestError(f"config: {part}: must be a table")
        out[dotted] = value
    return out


#: The config's file name in a job folder (and in the library's messages about it).
CONFIG_NAME = "config.toml"

#: The request setting behind each config field a setting overrides.
SETTING_OF = {dotted: f"settings.{key}" for key, dotted in OVERRIDES}


def _library_error(
    e: Exception, kind: str, overrides: dict[str, Any] | None = None, job_dir: Path | None = None
) -> RequestError:
    """A library error as the request's words: a parameter or an overridden field by its JSON setting.

    Files are named as the request names them (``sky.exr``), never by their place in the job folder.
    """
    from forest.errors import ParameterError

    if isinstance(e, ParameterError):
        line = f"{field_name(e.field or '', kind)}: {e.message}"
    elif isinstance(e, ConfigError) and overrides and e.field in overrides and e.field in SETTING_OF:
        line = f"{SETTING_OF[e.field]}: {e.message}"
    else:
        line = str(e)
    if job_dir is not None:
        line = line.replace(f"{job_dir}/", "").replace(str(job_dir), ".")
    if line.startswith(f"{CONFIG_NAME}: "):
        line = "config: " + line[len(CONFIG_NAME) + 2 :]  # the request's field, as for the TOML and the assets
    return RequestError(line)


def prepare(
    req: JobRequest, datadir: DataDir, limits: Limits, capabilities: dict[str, bool], *, local: bool = True
) -> PreparedJob:
    """Validate a request completely and lay out its job folder; raise :class:`RequestError`.

    ``local``: the tasks run on this machine (the local executor), so a render's memory estimate is
    checked against this machine's room (:attr:`Limits.check_memory`); on a cluster it is not.
    """
    from forest.config import Config, apply_overrides, read_toml
    from forest.errors import ForestError
    from forest.frames import parse_frames

    if not capabilities.get(req.kind):
        raise RequestError(
            f"kind: {req.kind} jobs are not available in this installation "
            f"(available: {', '.join(k for k, v in capabilities.items() if v) or 'none'})"
        )
    if len(req.config.encode()) > limits.max_config_bytes:
        raise RequestError(f"config: the config is over {limits.max_config_bytes // 1024} KiB", 413)
    try:
        data = read_toml(req.config)  # the CLI's parser: the same size and nesting limits, the same messages
    except ForestError as e:
        raise RequestError(f"config: {e.message}") from None
    s = req.settings
    try:
        assets = collect_assets(data, datadir)
        if req.kind == "match":
            if not s.reference:
                raise RequestError("settings.reference: match jobs need a reference photo (an uploaded image)")
            for key in ("reference", "mask"):
                name = getattr(s, key)
                if name is not None:
                    assets[name] = datadir.asset_path(name, field=f"settings.{key}")
                    if asset_kind(name) != "image":
                        raise RequestError(f"settings.{key}: must be an image")
        else:
            for key in ("reference", "mask"):
                if getattr(s, key) is not None:
                    raise RequestError(f"settings.{key}: applies to match jobs only")
    except AssetError as e:
        raise RequestError(str(e), e.status) from None

    job_id = uuid.uuid4().hex
    job_dir = datadir.job_dir(job_id)
    overrides = _overrides(s, data)
    named = isinstance(data.get("name"), str)
    try:
        # the TOML is parsed once; the settings are applied as the CLI applies its flags, and the
        # whole config is validated now (its files once they are linked into the job folder, below)
        data = apply_overrides(data, overrides)
        config = Config(data, path=Path(CONFIG_NAME), base_dir=job_dir, check_files=False)
        name = req.name or (config.name if named else None)
    except ForestError as e:
        raise _library_error(e, req.kind, overrides) from None
    try:
        inputs: dict[str, str] = {}
        if assets:
            # the job folder exists from submission on only when the config names assets;
            # otherwise the dispatcher creates it when the first task starts
            job_dir.mkdir(parents=True)
            link_into(job_dir, assets)
            inputs = {rel: file_sha256(job_dir / rel) for rel in sorted(assets)}
        try:
            config = Config(data, path=Path(CONFIG_NAME), base_dir=job_dir)
        except ForestError as e:
            raise _library_error(e, req.kind, overrides, job_dir) from None
        r = config.render
        width, height, spp = r.width, r.height, r.spp
        configured = config.lookdev.variant if req.kind == "match" else r.variant  # what the task renders with
        _check_limits(config, overrides, limits)
        candidates = config.scatter.count
        try:
            _check_inputs(config)
            if limits.check_memory and (local or limits.worker_memory_bytes is not None):
                _check_memory(
                    config, req.kind, s.variant or configured, s.preview, limits.worker_memory_bytes, overrides
                )
        except ForestError as e:
            raise _library_error(e, req.kind, overrides, job_dir) from None
        base: dict[str, Any] = {
            "job_id": job_id,
            "kind": req.kind,
            "config": req.config,
            "overrides": overrides,
            "variant": s.variant,
            "preview": s.preview,
            "quick_look": s.quick_look,
            "inputs": inputs,
            "memory_bytes": limits.worker_memory_bytes if limits.check_memory else None,
            "resources": Resources(cpus=s.cpus, gpus=s.gpus if s.gpus is not None else _gpus(s.variant or configured)),
        }
        frames: list[int] | None = None
        if s.frames is not None and req.kind not in ("flythrough", "rib", "usd"):
            raise RequestError("settings.frames: applies to flythrough, rib and usd jobs only")
        if req.kind in ("flythrough", "rib", "usd"):
            frames = _frames(s.frames, config, parse_frames, required=req.kind == "flythrough")
            if frames is not None and len(frames) > limits.max_frames:
                raise RequestError(
                    f"settings.frames: {len(frames)} frames is over the service limit of {limits.max_frames}"
                )
        specs: list[TaskSpec] = []
        if req.kind == "render":
            specs.append(TaskSpec(**base, index=0, output="out/render.exr", frames=(1,)))
        elif req.kind == "flythrough":
            assert frames is not None
            per = s.frames_per_task or 1
            for i in range(0, len(frames), per):
                specs.append(
                    TaskSpec(**base, index=len(specs), output="out/frame_####.exr", frames=tuple(frames[i : i + per]))
                )
        elif req.kind == "match":
            if s.iterations is not None and s.iterations > limits.max_iterations:
                raise RequestError(
                    f"settings.iterations: {s.iterations} is over the service limit of {limits.max_iterations}"
                )
            assert s.reference is not None
            match = MatchSpec(
                reference=s.reference,
                iterations=s.iterations,
                resolution=s.resolution,
                spp=s.match_spp,
                params=tuple(s.params) if s.params is not None else None,
                mode=s.mode,
            )
            _check_match(config, match, s.variant, limits, job_dir, overrides)
            specs.append(TaskSpec(**base, index=0, output="out", match=match))
        elif req.kind == "rib":
            specs.append(
                TaskSpec(
                    **base,
                    index=0,
                    output="out/rib",
                    frames=tuple(frames) if frames else None,
                    renderman22=s.renderman22,
                )
            )
        else:
            stem = "".join(c if c.isalnum() or c in "-_" else "_" for c in (name or "scene")) or "scene"
            specs.append(
                TaskSpec(**base, index=0, output=f"out/usd/{stem}.usdc", frames=tuple(frames) if frames else None)
            )
        if s.renderman22 and req.kind != "rib":
            raise RequestError("settings.renderman22: applies to rib jobs only")
    except BaseException:
        shutil.rmtree(job_dir, ignore_errors=True)
        raise
    settings = s.model_dump(mode="json", exclude_none=True, exclude_defaults=True)
    settings.update({"width": width, "height": height, "spp": spp, "candidates": candidates})
    if frames is not None:
        settings["frame_range"] = [frames[0], frames[-1], len(frames)]
    return PreparedJob(job_id=job_id, job_dir=job_dir, name=name, settings=settings, task_specs=specs)


def _gpus(variant: str | None) -> float | None:
    """A GPU for the CUDA variant (so a Ray cluster places the task on a GPU node).  None for the automatic choice:
    on Ray such a task renders on the CPU (an actor without a GPU hides the node's), unless ``settings.gpus`` gives
    it one, which it then uses where the GPU passed forest's self-check."""
    return 1.0 if str(variant or "").startswith("cuda") else None


def _frames(text: str | None, config: Any, parse_frames: Any, *, required: bool) -> list[int] | None:
    from forest.errors import ForestError

    if text:
        try:
            return parse_frames(text)
        except ForestError as e:
            raise _library_error(e, "flythrough") from None
    keys = config.camera.keys
    if len(keys) >= 2:
        return list(range(int(keys[0].frame), int(keys[-1].frame) + 1))
    if required:
        raise RequestError(
            "settings.frames: give a frame range, e.g. '1-24' (the config has no [camera] keys to take it from)"
        )
    return None


def _field(dotted: str, overrides: dict[str, Any]) -> str:
    """The request's name for a config field: its setting when a setting gave the value, else ``config: <field>``."""
    return SETTING_OF[dotted] if dotted in overrides else f"config: {dotted}"


def _check_limits(config: Any, overrides: dict[str, Any], limits: Limits) -> None:
    """The service's limits on image size, samples and candidates, named as the request gave each value."""
    r = config.render
    width, height, spp = r.width, r.height, r.spp
    w_field, h_field = _field("render.width", overrides), _field("render.height", overrides)
    both = f"{w_field}/{h_field.removeprefix('config: ')}" if w_field.startswith("config") else f"{w_field}/{h_field}"
    if width > limits.max_width or height > limits.max_height:
        raise RequestError(
            f"{both}: {width}x{height} is over the service limit of "
            f"{limits.max_width}x{limits.max_height} ({w_field if width > limits.max_width else h_field})"
        )
    if width * height > limits.max_pixels:
        raise RequestError(
            f"{w_field}×height: {width}×{height} = {width * height} pixels is over the "
            f"service limit of {limits.max_pixels}"
        )
    if spp > limits.max_spp:
        raise RequestError(f"{_field('render.spp', overrides)}: {spp} is over the service limit of {limits.max_spp}")
    candidates = config.scatter.count
    if candidates > limits.max_trees:
        raise RequestError(
            f"{_field('scatter.count', overrides)}: {candidates} candidate trees is over the service limit of "
            f"{limits.max_trees}"
        )


def _check_inputs(config: Any) -> None:
    """What the CLI checks before work starts, on the job's linked files (raises ``ForestError``).

    The species against the library (:func:`forest.preflight.check_species`), the
    environment map (:func:`forest.render.scene.check_envmap`: format, decodable,
    finite and non-negative radiance) and the terrain texture.  Mitsuba's own test
    load of an environment map is left to the worker, which has the renderer loaded.
    """
    from forest.ground import read_terrain_texture
    from forest.preflight import check_species
    from forest.render.scene import check_envmap

    check_species(config, _library())  # and how many tree variants the job would generate
    check_envmap(config)
    read_terrain_texture(config)


def _check_memory(
    config: Any, kind: str, variant: str | None, preview: bool, room: Any, overrides: dict[str, Any]
) -> None:
    """Refuse a render whose image alone needs more memory than the workers' machine has room for.

    The estimate is the CLI's before it loads the scene (:func:`forest.preflight.render_estimate` of the
    frame's size, no trees yet, in the variant the job names or else ``scalar_rgb``), compared with ``room``
    (bytes or a :class:`forest.memory.Room`; None: :func:`forest.preflight.memory_room` of this process, the
    machine the local workers share).  One line with the estimate and the room, naming the field that set
    the size.  Only ``render`` and ``flythrough`` jobs render frames.
    """
    if kind not in ("render", "flythrough"):
        return
    from forest import preflight
    from forest.render.render import frame_size

    found = preflight.memory_room() if room is None else room
    if found is None:
        return
    size = frame_size(config, preview=preview)
    estimate = preflight.render_estimate(size.width, size.height, size.spp, 0, variant or "scalar_rgb")
    try:
        preflight.check_render_memory(config, estimate, available=found)
    except ConfigError as e:
        raise RequestError(memory_line(e, overrides)) from None


def memory_line(e: ConfigError, overrides: dict[str, Any]) -> str:
    """A :func:`forest.preflight.check_render_memory` refusal (a ``ConfigError``) in the request's words: the
    settings that gave the size (``settings.width``) or the trees (``settings.count``), else the config's field
    (``config: render.width/render.height``) — at submission and in a worker alike."""
    if e.field == "render.width/render.height":
        given = [SETTING_OF[f] for f in ("render.width", "render.height") if f in overrides]
        if given:
            return f"{'/'.join(given)}: {e.message}"
    return f"{_field(e.field, overrides)}: {e.message}" if e.field else str(e.message)


class _Names:
    """A library's species names, read again only when one of its manifests changes."""

    def __init__(self) -> None:
        self._key: tuple | None = None
        self._names: list[str] = []
        self._lib: Any = None

    def names(self) -> list[str]:
        from forest.library import open_library
        from forest.library.core import MANIFEST

        if self._lib is None:
            self._lib = open_library()  # its folders are fixed for the process; its manifests are not
        lib = self._lib
        stamps = []
        for folder in (lib.root, lib.base):
            if folder is not None:
                try:
                    st = (folder / MANIFEST).stat()
                    stamps.append((str(folder), st.st_mtime_ns, st.st_size))
                except OSError:
                    stamps.append((str(folder), 0, 0))
        if tuple(stamps) != self._key:
            self._names, self._key = lib.names(), tuple(stamps)
        return list(self._names)

    @property
    def library(self) -> Any:
        """The library itself (what :func:`forest.preflight.variants_to_generate` asks which variants are built)."""
        from forest.library import open_library

        if self._lib is None:
            self._lib = open_library()
        return self._lib


_NAMES = _Names()


def _library() -> _Names:
    """What :func:`forest.preflight.check_species` asks of the library: its names (cached by manifest)."""
    return _NAMES


def _check_match(
    config: Any, match: MatchSpec, variant: str | None, limits: Limits, job_dir: Path, overrides: dict[str, Any]
) -> None:
    """Validate look-dev settings and the reference now (as ``forest match`` does), so mistakes answer 422."""
    import warnings

    from forest.errors import ForestError, ParameterError
    from forest.lookdev import optimiser_size, resolve_settings
    from forest.lookdev.reference import load_reference, painted_labels

    try:
        st = resolve_settings(
            config,
            iterations=match.iterations,
            resolution=match.resolution,
            spp=match.spp,
            params=list(match.params) if match.params is not None else None,
            mode=match.mode,
            variant=variant,
            pick_variant=False,  # the worker chooses; no GPU self-check in the service
        )
    except ForestError as e:
        raise _library_error(e, "match", job_dir=job_dir) from None
    if st.iterations > limits.max_iterations:
        raise RequestError(f"lookdev.iterations: {st.iterations} is over the service limit of {limits.max_iterations}")
    width, height = optimiser_size(config, st.resolution)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = load_reference(job_dir / match.reference, width, height, fit=st.fit)
    except ParameterError as e:
        raise _library_error(e, "match", job_dir=job_dir) from None
    except ForestError as e:
        raise _library_error(ParameterError("reference", str(e)), "match", job_dir=job_dir) from None
    if st.mask is not None:  # the painted regions, read and fitted to the reference as forest match does
        try:
            painted_labels(st.mask, ref, width, height, st.fit)
        except ForestError as e:
            raise _library_error(config.fail("lookdev.mask", e.message), "match", overrides, job_dir) from None
