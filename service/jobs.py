"""Job requests: the request schema, service limits, and splitting a job into tasks.

A request is checked in this order, each failure answering a 4xx with one line that
names the field: the JSON schema (pydantic), the config's TOML syntax, every asset path
in the config (inside the data folder, see :mod:`forest.service.assets`), the config's own
validation (``forest.config``), then the service's limits on resolution, samples,
candidates and frames.  Only then is the job stored, so a bad request leaves nothing.

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

from .assets import AssetError, DataDir, collect_assets, link_into
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
    max_config_bytes: int = MAX_CONFIG_BYTES  # the CLI's limit too
    max_iterations: int = 2000


class JobSettings(BaseModel):
    """Per-job settings; each overrides the matching key of the config."""

    model_config = ConfigDict(extra="forbid")
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
    gpus: float | None = Field(default=None, ge=0, le=64, description="GPUs to reserve per task (Ray executor).")
    preview: bool = Field(default=False, description="Fast low-quality preview render.")
    quick_look: bool = Field(default=True, description="Stills: show a small one-sample image before the first pass.")
    reference: str | None = Field(
        default=None, max_length=512, description="Match jobs: reference photo (an asset name)."
    )
    iterations: int | None = Field(default=None, ge=1, le=100000, description="Match jobs: optimisation steps.")
    resolution: int | None = Field(default=None, ge=8, le=4096, description="Match jobs: proxy render width in pixels.")
    match_spp: int | None = Field(default=None, ge=1, le=1024, description="Match jobs: samples per pixel per step.")
    params: list[str] | None = Field(default=None, max_length=32, description="Match jobs: which parameters to fit.")
    mode: str | None = Field(
        default=None, max_length=64, pattern=r"^[A-Za-z0-9_-]+$", description="Match jobs: fit mode."
    )
    renderman22: bool = Field(default=False, description="RIB jobs: RenderMan 22+ style (Procedural2, Pxr lights).")


class JobRequest(BaseModel):
    """``POST /jobs`` body."""

    model_config = ConfigDict(extra="forbid")
    kind: Kind = Field(..., description="render (a still), flythrough, match, rib or usd (exports).")
    config: str = Field(..., min_length=1, description="The scene config as TOML text (at most 1 MiB).")
    settings: JobSettings = Field(default_factory=lambda: JobSettings())
    priority: int = Field(0, ge=-100, le=100, description="Higher runs first.")
    name: str | None = Field(default=None, max_length=200, description="Default: the config's `name`.")


class RequestError(Exception):
    def __init__(self, message: str, status: int = 422):
        super().__init__(message)
        self.status = status


def request_hash(req: JobRequest) -> str:
    return hashlib.sha256(json.dumps(req.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()


@dataclass
class PreparedJob:
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


#: The request setting behind each config field a setting overrides.
SETTING_OF = {dotted: f"settings.{key}" for key, dotted in OVERRIDES}


def _library_error(e: Exception, kind: str, overrides: dict[str, Any] | None = None) -> RequestError:
    """A library error as the request's words: a parameter or an overridden field by its JSON setting."""
    from forest.errors import ConfigError, ParameterError

    if isinstance(e, ParameterError):
        return RequestError(f"{field_name(e.field or '', kind)}: {e.message}")
    if isinstance(e, ConfigError) and overrides and e.field in overrides and e.field in SETTING_OF:
        return RequestError(f"{SETTING_OF[e.field]}: {e.message}")
    return RequestError(str(e))


def prepare(req: JobRequest, datadir: DataDir, limits: Limits, capabilities: dict[str, bool]) -> PreparedJob:
    """Validate a request completely and lay out its job folder; raise :class:`RequestError`."""
    from forest.camera import parse_frames
    from forest.config import Config, apply_overrides, read_toml
    from forest.errors import ForestError

    if not capabilities.get(req.kind):
        raise RequestError(
            f"kind: {req.kind} jobs are not available in this installation "
            f"(available: {', '.join(k for k, v in capabilities.items() if v) or 'none'})"
        )
    if len(req.config.encode()) > limits.max_config_bytes:
        raise RequestError(f"config: larger than the {limits.max_config_bytes} byte limit", 413)
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
            ref = datadir.asset_path(s.reference, field="settings.reference")
            if ref.suffix.lower() not in (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".hdr"):
                raise RequestError("settings.reference: must be an image")
            assets[s.reference] = ref
        elif s.reference is not None:
            raise RequestError("settings.reference: applies to match jobs only")
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
        config = Config(data, path=Path("config.toml"), base_dir=job_dir, check_files=False)
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
            config = Config(data, path=Path("config.toml"), base_dir=job_dir)
        except ForestError as e:
            raise _library_error(e, req.kind, overrides) from None
        r = config.render
        width, height, spp = r.width, r.height, r.spp
        if width > limits.max_width:
            raise RequestError(f"settings.width: {width} is over the service limit of {limits.max_width}")
        if height > limits.max_height:
            raise RequestError(f"settings.height: {height} is over the service limit of {limits.max_height}")
        if width * height > limits.max_pixels:
            raise RequestError(
                f"settings.width×height: {width}×{height} = {width * height} pixels is over the "
                f"service limit of {limits.max_pixels}"
            )
        if spp > limits.max_spp:
            raise RequestError(f"settings.spp: {spp} is over the service limit of {limits.max_spp}")
        candidates = config.scatter.count
        if candidates > limits.max_trees:
            raise RequestError(
                f"settings.count: {candidates} candidate trees is over the service limit of {limits.max_trees}"
            )
        base: dict[str, Any] = {
            "job_id": job_id,
            "kind": req.kind,
            "config": req.config,
            "overrides": overrides,
            "variant": s.variant,
            "preview": s.preview,
            "quick_look": s.quick_look,
            "inputs": inputs,
            "resources": Resources(cpus=s.cpus, gpus=s.gpus if s.gpus is not None else _gpus(s.variant or r.variant)),
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
            _check_match(config, match, s.variant, limits)
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
    """A GPU for the CUDA variant (so a Ray cluster places the task on a GPU node)."""
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


def _check_match(config: Any, match: MatchSpec, variant: str | None, limits: Limits) -> None:
    """Validate look-dev settings now (the same resolution look-dev does), so mistakes answer 422."""
    from forest.errors import ForestError
    from forest.lookdev import resolve_settings

    try:
        st = resolve_settings(
            config,
            iterations=match.iterations,
            resolution=match.resolution,
            spp=match.spp,
            params=list(match.params) if match.params is not None else None,
            mode=match.mode,
            variant=variant,
        )
    except ForestError as e:
        raise _library_error(e, "match") from None
    if st.iterations > limits.max_iterations:
        raise RequestError(f"lookdev.iterations: {st.iterations} is over the service limit of {limits.max_iterations}")
