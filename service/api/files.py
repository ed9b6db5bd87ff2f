"""A job's files: result, downloads, logs, preview.

=====================================  ===================================================
``GET /jobs/{id}/result``              outputs, the main image, downloads, statistics
                                       (409 before the job succeeded)
``GET /jobs/{id}/files/{path}``        one file under ``out/``, ``thumbs/`` or ``preview/``
``GET /jobs/{id}/outputs.zip``         the outputs as one zip (``?ext=exr``, ``?folder=out/rib``)
``GET /jobs/{id}/preview``             the newest image (PNG)
``GET /jobs/{id}/log``                 the job's log (text, its last MiB)
``GET /jobs/{id}/tasks/{i}/log``       one task's log
=====================================  ===================================================

Each answers ``HEAD`` too: the same status and headers, no body.  Files of a job the store has forgotten stay downloadable while its folder exists.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi.responses import FileResponse, PlainTextResponse
from fastapi.routing import APIRoute

from ..assets import AssetError, check_relative, is_inside
from ..downloads import archive, collect
from .deps import Service, job_or_404, service
from .schemas import ERRORS, ResultView

router = APIRouter()
SERVED = ("out/", "thumbs/", "preview/")
BEAUTY_SKIP = ("depth", "mask", "_id", "species")


def _file(svc: Service, job_id: str, rel: str, *, cache: bool) -> FileResponse:
    try:
        check_relative(rel, field="path")
        root = svc.datadir.job_dir(job_id).resolve()
    except AssetError as e:
        raise HTTPException(404, str(e)) from None
    p = (root / rel).resolve()
    if not is_inside(p, root) or not p.is_file():
        raise HTTPException(404, f"{rel} not found")
    headers = {} if cache else {"Cache-Control": "no-store"}
    return FileResponse(p, headers=headers)


def downloads(job: dict, outputs: list[str]) -> list[dict]:
    """Links to the useful bundles and files of a job's outputs."""
    jid, kind = job["id"], job["kind"]
    base = f"/jobs/{jid}/outputs.zip"
    out: list[dict] = []
    if kind in ("render", "flythrough"):
        what = "frames" if kind == "flythrough" else "image"
        out += [{"label": f"EXR {what} (zip)", "url": f"{base}?ext=exr"}]
        out += [{"label": f"PNG {what} (zip)", "url": f"{base}?ext=png"}]
    elif kind == "rib":
        out.append({"label": "RIB export (zip)", "url": f"{base}?folder=out/rib"})
    elif kind == "usd":
        out.append({"label": "USD stage and species layers (zip)", "url": f"{base}?folder=out/usd"})
    elif kind == "match":
        names = {
            "scene.toml": "fitted scene (scene.toml)",
            "report.png": "look-dev report (report.png)",
            "match.json": "figures (match.json)",
        }
        for rel in outputs:
            name = rel.rsplit("/", 1)[-1]
            if name in names:
                out.append({"label": names[name], "url": f"/jobs/{jid}/files/{rel}"})
            elif name.startswith("colour_map"):
                out.append({"label": f"fitted colour map ({name})", "url": f"/jobs/{jid}/files/{rel}"})
    out.append({"label": "all outputs (zip)", "url": base})
    return out


@router.get("/jobs/{job_id}/result", response_model=ResultView, responses=ERRORS, summary="Outputs of a succeeded job")
def result(job_id: str, svc: Service = Depends(service)) -> dict:
    """The files a succeeded job wrote (``out/``, ``thumbs/``, ``preview/``), its main image, download links and
    statistics; 409 while it has not succeeded or once its outputs were deleted.
    """
    job = job_or_404(svc, job_id, archived=True)
    if job["state"] != "succeeded":
        msg = f"job {job_id} is {job['state']}"
        if job.get("error"):
            msg += f": {job['error']}"
        raise HTTPException(409, msg)
    if job.get("outputs_deleted"):
        raise HTTPException(409, f"the outputs of job {job_id} were deleted")
    res = job.get("result") or {"outputs": [], "stats": []}
    root = svc.datadir.job_dir(job_id)
    outs = []
    for rel in res.get("outputs", []):
        p = root / rel
        if p.is_file() and rel.startswith(SERVED):
            outs.append({"path": rel, "url": f"/jobs/{job_id}/files/{rel}", "bytes": p.stat().st_size})
    pngs = [o["url"] for o in outs if o["path"].startswith("out/") and o["path"].endswith(".png")]
    beauty = [u for u in pngs if not any(t in u.rsplit("/", 1)[-1] for t in BEAUTY_SKIP)]
    return {
        "id": job_id,
        "outputs": outs,
        "image": (beauty or pngs or [None])[0],
        "downloads": downloads(job, [o["path"] for o in outs]),
        "stats": res.get("stats", []),
    }


@router.get(
    "/jobs/{job_id}/files/{path:path}",
    responses={**ERRORS, 200: {"content": {"application/octet-stream": {}}}},
    response_class=FileResponse,
    summary="A file of a job (outputs, thumbnails, previews)",
)
def job_file(job_id: str, path: str, svc: Service = Depends(service)) -> FileResponse:
    """One file of a job under ``out/``, ``thumbs/`` or ``preview/`` (previews are not cached); 404 elsewhere."""
    job_or_404(svc, job_id, archived=True)
    if not path.startswith(SERVED):
        raise HTTPException(404, "only out/, thumbs/ and preview/ files are served")
    return _file(svc, job_id, path, cache=not path.startswith("preview/"))


@router.get(
    "/jobs/{job_id}/outputs.zip",
    responses={**ERRORS, 200: {"content": {"application/zip": {}}}},
    response_class=FileResponse,
    summary="A job's outputs as one zip archive",
)
def outputs_zip(
    job_id: str,
    ext: str | None = Query(None, pattern=r"^[A-Za-z0-9]{1,8}$", description="Only files ending in .ext"),
    folder: str = Query("out", max_length=200, pattern=r"^out(/[A-Za-z0-9._-]+)*$", description="A folder of out/"),
    svc: Service = Depends(service),
) -> FileResponse:
    """A zip of the files under ``folder`` (default ``out``), with ``ext`` only those ending in it; 404 if none."""
    job = job_or_404(svc, job_id, archived=True)
    root = svc.datadir.job_dir(job_id)
    try:
        check_relative(folder, field="folder")
    except AssetError as e:
        raise HTTPException(422, str(e)) from None
    if not is_inside((root / folder).resolve(), root.resolve()):
        raise HTTPException(404, f"{folder} not found")
    files = collect(root, folder, ext.lower() if ext else None)
    if not files:
        raise HTTPException(404, f"no {'.' + ext + ' ' if ext else ''}files under {folder}/ yet")
    path = archive(root, files, folder)
    stem = "".join(c if c.isalnum() or c in "-_" else "_" for c in (job.get("name") or job_id[:8]))
    suffix = f"-{ext.lower()}" if ext else ("" if folder == "out" else "-" + Path(folder).name)
    return FileResponse(path, media_type="application/zip", filename=f"{stem}{suffix}.zip")


@router.get(
    "/jobs/{job_id}/preview",
    responses={**ERRORS, 200: {"content": {"image/png": {}}}},
    response_class=FileResponse,
    summary="The newest image of a job (PNG)",
)
def preview(job_id: str, svc: Service = Depends(service)) -> FileResponse:
    """The job's newest preview image (not cached); 404 until there is one."""
    job = job_or_404(svc, job_id)
    if not job.get("preview"):
        raise HTTPException(404, f"job {job_id} has no preview yet")
    return _file(svc, job_id, job["preview"], cache=False)


def _tail(p: Path) -> PlainTextResponse:
    if not p.is_file():
        return PlainTextResponse("")
    with open(p, "rb") as f:
        size = p.stat().st_size
        f.seek(max(0, size - 2**20))
        return PlainTextResponse(f.read().decode("utf-8", errors="replace"))


@router.get("/jobs/{job_id}/log", response_class=PlainTextResponse, responses=ERRORS, summary="The job's log")
def job_log(job_id: str, svc: Service = Depends(service)) -> PlainTextResponse:
    """The last MiB of the job's log (empty before it has one)."""
    job_or_404(svc, job_id, archived=True)
    return _tail(svc.datadir.job_dir(job_id) / "job.log")


@router.get(
    "/jobs/{job_id}/tasks/{index}/log", response_class=PlainTextResponse, responses=ERRORS, summary="One task's log"
)
def task_log(job_id: str, index: int, svc: Service = Depends(service)) -> PlainTextResponse:
    """The last MiB of task ``index``'s log (empty before it has one); 404 for a task the job does not have."""
    job = job_or_404(svc, job_id, archived=True)
    if not 0 <= index < 1_000_000 or (not job.get("archived") and svc.db.get_task(job_id, index) is None):
        raise HTTPException(404, f"job {job_id} has no task {index}")
    return _tail(svc.datadir.job_dir(job_id) / "logs" / f"task-{index:04d}.log")


def _add_head_routes() -> None:
    """``HEAD`` for every download above: the same status and headers as ``GET`` (``Content-Length``,
    ``Content-Type``, ``Content-Disposition``), no body — what download managers and farm tools ask first.
    Left out of the OpenAPI document, which lists the ``GET``\\ s."""
    for route in list(router.routes):
        if isinstance(route, APIRoute) and "GET" in (route.methods or ()):
            router.add_api_route(
                route.path,
                route.endpoint,
                methods=["HEAD"],
                response_class=route.response_class,
                include_in_schema=False,
                name=f"{route.name}_head",
            )


_add_head_routes()
