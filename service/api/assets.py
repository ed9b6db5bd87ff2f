"""Assets: ``PUT /assets/{path}`` uploads a map, mesh or photo (folders kept), ``GET /assets`` lists them."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Depends, HTTPException, Request

from ..assets import AssetError, store_upload
from .deps import Service, service
from .schemas import ERRORS, AssetView

router = APIRouter()


@router.put(
    "/assets/{name:path}",
    status_code=201,
    response_model=AssetView,
    responses=ERRORS,
    summary="Upload a map, mesh or reference photo (the raw file as the body; e.g. maps/height.png)",
)
async def upload(name: str, request: Request, svc: Service = Depends(service)) -> dict:
    """Store the request body as ``assets/{name}`` (folders kept; a file of that name is replaced).

    413 past the upload limit, 415 for an extension that is no image or mesh, 422 for an unsafe
    name or a file that does not read as what its extension says.
    """
    limit = svc.config.limits.max_upload_bytes
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > limit:
        raise HTTPException(413, f"upload is larger than the {limit} byte limit")
    chunks: list[bytes] = []
    size = 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise HTTPException(413, f"upload is larger than the {limit} byte limit")
        chunks.append(chunk)
    try:
        decoded = svc.config.limits.max_decoded_bytes
        return await asyncio.to_thread(store_upload, svc.datadir, name, iter(chunks), limit, decoded)
    except AssetError as e:
        raise HTTPException(e.status, f"{name}: {e}") from None


@router.get("/assets", response_model=list[AssetView], summary="Uploaded assets (paths inside assets/)")
def assets(svc: Service = Depends(service)) -> list[dict]:
    """Every uploaded file under ``assets/``, sorted by name, with its size and kind (image or mesh)."""
    return svc.datadir.list_assets()
