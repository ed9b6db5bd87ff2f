"""Job requests: the request schema, service limits, and splitting a job into tasks.

A request is checked in this order, each failure answering a 4xx with one line that
names the field: the JSON schema (pydantic), the config's TOML syntax, every asset path
in the config (inside the data folder, see :mod:`forest.service.assets`), the config's own
validation (``forest.config``), then the service's limits on resolution, samples,
tree count and frames.  Only then is the job stored, so a bad request leaves nothing.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import tomllib
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from .assets import AssetError, DataDir, collect_assets, link_into

Kind = Literal["render", "flythrough", "match"]
Variant = Literal["scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"]


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
    max_config_bytes: int = 256 * 1024
    max_iterations: int = 2000


class JobSettings(BaseModel):
    """Per-job settings; each overrides the matching key of the config."""

    model_config = ConfigDict(extra="forbid")
    width: int | None = Field(None, ge=1, le=16384, description="Image width in pixels ([render] width).")
    height: int | None = Field(None, ge=1, le=16384, description="Image height in pixels ([render] height).")
    spp: int | None = Field(None, ge=1, le=65536, description="Samples per pixel ([render] spp).")
    variant: Variant | None = Field(None, description="Mitsuba variant; default: the renderer's choice.")
    seed: int | None = Field(None, ge=0, le=2**63 - 1, description="Scene seed (top-level seed).")
    count: int | None = Field(None, ge=0, le=20_000_000, description="Tree count ([scatter] count).")
    frames: str | None = Field(
        None, max_length=200, pattern=r"^[0-9xX,\- ]+$", description="Fly-through frames, e.g. '1-24' or '1-120x2'."
    )
    frames_per_task: int | None = Field(None, ge=1, le=10000, description="Frames per fly-through task.")
    cpus: float | None = Field(None, gt=0, le=1024, description="CPUs to reserve per task (Ray executor).")
    gpus: float | None = Field(None, ge=0, le=64, description="GPUs to reserve per task (Ray executor).")
    preview: bool = Field(False, description="Fast low-quality preview render.")
    reference: str | None = Field(None, max_length=512, description="Match jobs: reference photo (an asset name).")
    iterations: int | None = Field(None, ge=1, le=100000, description="Match jobs: optimisation steps.")
    resolution: int | None = Field(None, ge=8, le=4096, description="Match jobs: proxy render width in pixels.")
    match_spp: int | None = Field(None, ge=1, le=1024, description="Match jobs: samples per pixel per step.")
    params: list[str] | None = Field(None, max_length=32, description="Match jobs: which parameters to fit.")
    mode: str | None = Field(None, max_length=64, pattern=r"^[A-Za-z0-9_-]+$", description="Match jobs: fit mode.")


class JobRequest(BaseModel):
    """``POST /jobs`` body."""

    model_config = ConfigDict(extra="forbid")
    kind: Kind
    config: str = Field(..., min_length=1, max_length=1_000_000, description="The scene config as TOML text.")
    settings: JobSettings = Field(default_factory=JobSettings)
    priority: int = Field(0, ge=-100, le=100, description="Higher runs first.")
    name: str | None = Field(None, max_length=200)


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
    settings: dict
    task_specs: list[dict]


def _overrides(s: JobSettings) -> dict:
    o = {}
    for key, dotted in (
        ("width", "render.width"),
        ("height", "render.height"),
        ("spp", "render.spp"),
        ("seed", "seed"),
        ("count", "scatter.count"),
    ):
        v = getattr(s, key)
        if v is not None:
            o[dotted] = v
    if s.variant is not None:
        o["render.variant"] = s.variant
    return o


def prepare(req: JobRequest, datadir: DataDir, limits: Limits, capabilities: dict[str, bool]) -> PreparedJob:
    """Validate a request completely and lay out its job folder; raise :class:`RequestError`."""
    from forest.camera import parse_frames
    from forest.config import Config, apply_overrides
    from forest.errors import ForestError

    if not capabilities.get(req.kind):
        raise RequestError(
            f"kind: {req.kind} jobs are not available in this installation "
            f"(available: {', '.join(k for k, v in capabilities.items() if v) or 'none'})"
        )
    if len(req.config.encode()) > limits.max_config_bytes:
        raise RequestError(f"config: larger than the {limits.max_config_bytes} byte limit", 413)
    try:
        data = tomllib.loads(req.config)
    except tomllib.TOMLDecodeError as e:
        raise RequestError(f"config: invalid TOML: {e}") from None
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
    overrides = _overrides(s)
    # The TOML is parsed once; the settings are applied as the CLI applies its flags.
    try:
        data = apply_overrides(data, overrides)
        config = Config(data, path=Path("config.toml"), base_dir=job_dir, check_files=False)
    except ForestError as e:
        raise RequestError(str(e)) from None
    try:
        if assets:
            # the job folder exists from submission on only when the config names assets;
            # otherwise the worker creates it (and writes config.toml) when the task starts
            job_dir.mkdir(parents=True)
            link_into(job_dir, assets)
        try:
            config = Config(data, path=Path("config.toml"), base_dir=job_dir)
        except ForestError as e:
            raise RequestError(str(e)) from None
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
        trees = config.scatter.count
        if trees > limits.max_trees:
            raise RequestError(f"settings.count: {trees} trees is over the service limit of {limits.max_trees}")
        base = {
            "kind": req.kind,
            "job_dir": str(job_dir),
            "config": req.config,
            "overrides": overrides,
            "variant": s.variant,
            "preview": s.preview,
        }
        res = {k: v for k, v in (("cpus", s.cpus), ("gpus", s.gpus)) if v is not None}
        if res:
            base["resources"] = res
        specs: list[dict] = []
        if req.kind == "render":
            if s.frames is not None:
                raise RequestError("settings.frames: applies to flythrough jobs only")
            specs.append({**base, "index": 0, "output": "out/render.exr", "frames": None})
        elif req.kind == "flythrough":
            if not s.frames:
                keys = config.camera.keys
                if len(keys) < 2:
                    raise RequestError(
                        "settings.frames: give a frame range, e.g. '1-24' "
                        "(the config has no [camera] keys to take it from)"
                    )
                frames = list(range(int(keys[0].frame), int(keys[-1].frame) + 1))
            else:
                try:
                    frames = parse_frames(s.frames)
                except ForestError as e:
                    raise RequestError(f"settings.frames: {str(e).split(': ', 1)[-1]}") from None
            if len(frames) > limits.max_frames:
                raise RequestError(
                    f"settings.frames: {len(frames)} frames is over the service limit of {limits.max_frames}"
                )
            per = s.frames_per_task or max(1, -(-len(frames) // 8))
            for i in range(0, len(frames), per):
                specs.append(
                    {**base, "index": len(specs), "output": "out/frame_####.exr", "frames": frames[i : i + per]}
                )
        else:
            if s.iterations is not None and s.iterations > limits.max_iterations:
                raise RequestError(
                    f"settings.iterations: {s.iterations} is over the service limit of {limits.max_iterations}"
                )
            match = {
                "reference": s.reference,
                "iterations": s.iterations,
                "resolution": s.resolution,
                "spp": s.match_spp,
                "params": s.params,
                "mode": s.mode,
            }
            _check_match(config, match, s.variant, limits)
            specs.append({**base, "index": 0, "output": "out", "frames": None, "match": match})
    except BaseException:
        shutil.rmtree(job_dir, ignore_errors=True)
        raise
    settings = s.model_dump(mode="json", exclude_none=True)
    settings.update({"width": width, "height": height, "spp": spp, "trees": trees})
    if req.name:
        settings["name"] = req.name
    return PreparedJob(job_id=job_id, job_dir=job_dir, settings=settings, task_specs=specs)


def _check_match(config, match: dict, variant: str | None, limits: Limits) -> None:
    """Validate look-dev settings now (the same resolution look-dev does), so mistakes answer 422."""
    from forest.errors import ForestError, ParameterError
    from forest.lookdev import resolve_settings

    names = {
        "lookdev.iterations": "settings.iterations",
        "lookdev.resolution": "settings.resolution",
        "lookdev.spp": "settings.match_spp",
        "lookdev.mode": "settings.mode",
        "lookdev.variant": "settings.variant",
        "lookdev.params": "settings.params",
    }
    try:
        st = resolve_settings(
            config,
            iterations=match["iterations"],
            resolution=match["resolution"],
            spp=match["spp"],
            params=match["params"],
            mode=match["mode"],
            variant=variant,
        )
    except ForestError as e:
        # an error in a job setting names the setting's JSON field; one in the config, the config's field
        if isinstance(e, ParameterError) and e.field in names:
            raise RequestError(f"{names[e.field]}: {e.message}") from None
        raise RequestError(str(e)) from None
    if st.iterations > limits.max_iterations:
        raise RequestError(f"lookdev.iterations: {st.iterations} is over the service limit of {limits.max_iterations}")
