"""A Python client of the forest job service (``forest serve``), on httpx.

:class:`ServiceClient` speaks the service's HTTP API (``docs/openapi.json``): it uploads
the files a scene config names, submits a job, reads its state, waits for it with
progress, cancels it and downloads its outputs.  ``forest submit`` is this client on the
command line; a pipeline script uses it directly::

    from forest.client import ServiceClient

    with ServiceClient("http://farm-head:8000", token=token) as client:
        job = client.submit_scene("shots/valley/scene.toml", kind="flythrough", settings={"frames": "1-24"})
        client.wait(job["id"], on_update=lambda j: print(f"Progress: {round(100 * j['progress'])}%"))
        client.download(job["id"], "renders/valley")

A scene's maps and meshes upload under the paths the config names them by, relative to
the config's folder (``maps/height.png``), as the service expects (its assets keep their
folders); a config naming a file outside its folder or by an absolute path cannot be
submitted as it is.

Errors are :class:`ServiceError` (a :class:`forest.errors.ForestError`, one line): the
service unreachable, a request it refused (its own one-line reason, with the HTTP
status), a job that failed (:class:`JobFailed`, exit status 1, with the job's error).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
import urllib.parse
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path, PurePosixPath
from typing import Any

import httpx

from .errors import ForestError

#: Job kinds the service runs (``POST /jobs`` ``kind``).
KINDS = ("render", "flythrough", "match", "rib", "usd")
#: Job states after which nothing more happens.
TERMINAL = ("succeeded", "failed", "canceled")
#: The environment variables ``forest submit`` reads its server and token from.
SERVER_ENV = "FOREST_SERVER"
TOKEN_ENV = "FOREST_SERVICE_TOKEN"
DEFAULT_SERVER = "http://127.0.0.1:8000"


class ServiceError(ForestError):
    """The service could not be reached or refused a request: one line; ``status`` is the HTTP status (None when
    there was no answer)."""

    def __init__(self, message: str, status: int | None = None):
        super().__init__(message)
        self.status = status
        if status is not None and status >= 500:
            self.exit_code = 1  # the service's failure, not the user's mistake


class JobFailed(ServiceError):
    """A job ended failed or canceled: its error line; exit status 1."""

    exit_code = 1

    def __init__(self, job: dict[str, Any]):
        self.job = job
        state = job.get("state", "failed")
        line = f"job {job.get('id')} {'was canceled' if state == 'canceled' else 'failed'}"
        error = job.get("error") or _task_error(job)
        super().__init__(f"{line}: {error}" if error else line)
        self.exit_code = 1


def _task_error(job: dict[str, Any]) -> str | None:
    for task in job.get("tasks") or ():
        if task.get("error"):
            return str(task["error"])
    return None


def _detail(response: httpx.Response) -> str:
    """The service's one line for a refused request (``{"detail": …}``), else the start of the body."""
    try:
        data = response.json()
    except ValueError:
        data = None
    if isinstance(data, dict) and isinstance(data.get("detail"), str):
        return data["detail"]
    if isinstance(data, dict) and isinstance(data.get("detail"), list) and data["detail"]:
        first = data["detail"][0]
        return str(first.get("msg", first)) if isinstance(first, dict) else str(first)
    text = " ".join(response.text.split())[:200]
    return text or response.reason_phrase or "no reason given"


def scene_files(scene: str | Path) -> tuple[str, list[tuple[str, Path]]]:
    """A scene config's text and the files it names, as ``(upload name, local file)`` pairs.

    The names are the config's own paths (relative to its folder, ``./`` dropped): what the
    service looks them up by.  Raises :class:`ForestError` for a config that cannot be read,
    or that names a missing file, an absolute path or one outside its folder.
    """
    from .config import MAX_CONFIG_BYTES, file_values, read_toml

    path = Path(scene)
    if not path.is_file():
        what = "is a folder, not a config file" if path.is_dir() else "config file not found"
        raise ForestError(f"{path}: {what}")
    try:
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise ForestError(f"{path}: the config is over {MAX_CONFIG_BYTES // 1024} KiB")
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise ForestError(f"{path}: cannot read config: {e}") from None
    data = read_toml(text, path)
    base = path.resolve().parent
    files: dict[str, Path] = {}
    for field, value in file_values(data):
        name = _upload_name(value)
        if name is None:
            raise ForestError(
                f"{path}: {field}: {value!r} is outside the config's folder; the service takes files beside the "
                "config or in folders below it (copy it there and name it by a relative path)"
            )
        local = base / name
        if not local.is_file():
            raise ForestError(f"{path}: {field}: {value}: file not found")
        files[name] = local
    return text, sorted(files.items())


def _upload_name(value: str) -> str | None:
    """A config's relative file path as the service names the asset; None for absolute or climbing paths."""
    if not value or "\\" in value or value.startswith(("/", "~")) or (len(value) > 1 and value[1] == ":"):
        return None
    parts = [p for p in PurePosixPath(value).parts if p != "."]
    if not parts or ".." in parts:
        return None
    return "/".join(parts)


class ServiceClient:
    """A connection to one forest service: upload, submit, look at, wait for, cancel and download jobs.

    ``server`` is the service's base URL (``http://host:8000``); ``token`` its bearer token
    when it has one.  Use it as a context manager, or call :meth:`close`.
    """

    def __init__(
        self,
        server: str = DEFAULT_SERVER,
        *,
        token: str | None = None,
        timeout: float = 60.0,
        transport: httpx.BaseTransport | None = None,
    ):
        server = server.strip().rstrip("/")
        if not server.startswith(("http://", "https://")):
            server = f"http://{server}"
        self.server = server
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._http = httpx.Client(base_url=server, headers=headers, timeout=timeout, transport=transport)

    def __enter__(self) -> ServiceClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection pool."""
        self._http.close()

    # -- requests ------------------------------------------------------------------

    def _request(self, method: str, url: str, *, what: str, **kwargs: Any) -> httpx.Response:
        """One request; a transport failure or an error status as :class:`ServiceError` (``what`` says what was
        being done, for the message)."""
        try:
            response = self._http.request(method, url, **kwargs)
        except httpx.TimeoutException:
            raise ServiceError(f"{self.server}: no answer while {what} (timed out)") from None
        except httpx.TransportError as e:
            reason = str(e) or type(e).__name__
            if isinstance(e, httpx.ConnectError):
                raise ServiceError(f"{self.server}: cannot reach the forest service: {reason}") from None
            raise ServiceError(f"{self.server}: the connection failed while {what}: {reason}") from None
        if response.status_code >= 400:
            raise self._refused(response, what)
        return response

    def _refused(self, response: httpx.Response, what: str) -> ServiceError:
        status = response.status_code
        if status == 401:
            return ServiceError(
                f"{self.server}: the service needs its bearer token (--token or ${TOKEN_ENV}) "
                f"and {'got none' if 'Authorization' not in self._http.headers else 'refused the one given'}",
                status,
            )
        how = "the service failed" if status >= 500 else "refused"
        return ServiceError(f"{what}: {how} ({status}): {_detail(response)}", status)

    def health(self) -> dict[str, Any]:
        """``GET /health``: executor, workers, jobs per state, capabilities and limits."""
        return self._request("GET", "/health", what="asking for its health").json()

    def upload(self, file: str | Path, name: str) -> dict[str, Any]:
        """Upload ``file`` as the asset ``name`` (``maps/height.png``; folders kept); the service's view of it."""
        path = Path(file)
        url = "/assets/" + urllib.parse.quote(name, safe="/")
        try:
            with open(path, "rb") as f:
                return self._request(
                    "PUT",
                    url,
                    what=f"uploading {name}",
                    content=f,
                    headers={"Content-Type": "application/octet-stream"},
                ).json()
        except OSError as e:
            raise ForestError(f"{path}: cannot read: {e.strerror or e}") from None

    def submit(
        self,
        kind: str,
        config: str,
        *,
        settings: dict[str, Any] | None = None,
        name: str | None = None,
        priority: int = 0,
        idempotency_key: str | None = None,
    ) -> dict[str, Any]:
        """``POST /jobs``: submit a job of ``kind`` over the config text; the job as the service sees it (its
        ``id``, ``state``, ``links``).  The config's files must have been uploaded (see :meth:`submit_scene`)."""
        if kind not in KINDS:
            raise ForestError(f"kind: must be one of {', '.join(KINDS)}, got {kind!r}")
        body: dict[str, Any] = {"kind": kind, "config": config, "priority": priority}
        if settings:
            body["settings"] = {k: v for k, v in settings.items() if v is not None}
        if name is not None:
            body["name"] = name
        headers = {"Idempotency-Key": idempotency_key} if idempotency_key else {}
        return self._request("POST", "/jobs", what="submitting the job", json=body, headers=headers).json()

    def submit_scene(
        self,
        scene: str | Path,
        kind: str = "render",
        *,
        settings: dict[str, Any] | None = None,
        name: str | None = None,
        priority: int = 0,
        reference: str | Path | None = None,
        mask: str | Path | None = None,
        idempotency_key: str | None = None,
        on_upload: Callable[[str, Path], None] | None = None,
    ) -> dict[str, Any]:
        """Upload the files a scene config names (and a match job's ``reference`` photo and ``mask``), then
        submit it: the job as :meth:`submit` returns it.  ``on_upload(name, file)`` is told of each upload."""
        if kind not in KINDS:
            raise ForestError(f"kind: must be one of {', '.join(KINDS)}, got {kind!r}")
        text, files = scene_files(scene)
        settings = dict(settings or {})
        base = Path(scene).resolve().parent
        for key, photo in (("reference", reference), ("mask", mask)):
            if photo is None:
                continue
            p = Path(photo)
            if not p.is_file():
                raise ForestError(f"{p}: {'is a folder' if p.is_dir() else 'file not found'}", field=key)
            try:
                asset = p.resolve().relative_to(base).as_posix()
            except ValueError:
                asset = p.name
            files.append((asset, p))
            settings[key] = asset
        for asset, local in files:
            if on_upload is not None:
                on_upload(asset, local)
            self.upload(local, asset)
        return self.submit(kind, text, settings=settings, name=name, priority=priority, idempotency_key=idempotency_key)

    def job(self, job_id: str) -> dict[str, Any]:
        """``GET /jobs/{id}``: state, progress, times, ETA, tasks."""
        return self._request("GET", f"/jobs/{job_id}", what=f"reading job {job_id}").json()

    def cancel(self, job_id: str) -> dict[str, Any]:
        """``POST /jobs/{id}/cancel``: stop the job (queued tasks at once, running ones killed)."""
        return self._request("POST", f"/jobs/{job_id}/cancel", what=f"canceling job {job_id}").json()

    def result(self, job_id: str) -> dict[str, Any]:
        """``GET /jobs/{id}/result``: the outputs of a succeeded job."""
        return self._request("GET", f"/jobs/{job_id}/result", what=f"reading job {job_id}'s result").json()

    def wait(
        self,
        job_id: str,
        *,
        interval: float = 1.0,
        timeout: float | None = None,
        on_update: Callable[[dict[str, Any]], None] | None = None,
        patience: float = 60.0,
        check: bool = True,
    ) -> dict[str, Any]:
        """Poll the job every ``interval`` seconds until it ends; ``on_update(job)`` sees each reading.

        A service that stops answering for up to ``patience`` seconds (a restart) is waited
        for.  Returns the finished job; with ``check`` a failed or canceled job raises
        :class:`JobFailed`.  Past ``timeout`` seconds a :class:`ServiceError` says so (the job
        goes on).
        """
        start = time.monotonic()
        lost_since: float | None = None
        while True:
            try:
                job = self.job(job_id)
                lost_since = None
            except ServiceError as e:
                if e.status is not None and e.status < 500:
                    raise
                lost_since = lost_since if lost_since is not None else time.monotonic()
                if time.monotonic() - lost_since > patience:
                    raise
                time.sleep(min(5.0, max(interval, 0.5)))
                continue
            if on_update is not None:
                on_update(job)
            if job.get("state") in TERMINAL:
                if check and job["state"] != "succeeded":
                    raise JobFailed(job)
                return job
            if timeout is not None and time.monotonic() - start > timeout:
                raise ServiceError(
                    f"job {job_id} is still {job.get('state')} after {timeout:g} s (it goes on; "
                    f"{self.server}/#job={job_id})"
                )
            time.sleep(interval)

    def download(self, job_id: str, outdir: str | Path, *, ext: str | None = None, folder: str = "out") -> list[Path]:
        """Download a job's outputs (``folder`` of its ``out/``; only ``.ext`` files with ``ext``) into ``outdir``,
        keeping their folders; the files written.  Each file appears whole or not at all."""
        from .atomic import atomic_dir

        params = {"folder": folder, **({"ext": ext} if ext else {})}
        dest = Path(outdir)
        with tempfile.TemporaryDirectory(prefix=".forest-download.", dir=_existing_parent(dest)) as tmp:
            archive = Path(tmp) / "outputs.zip"
            with self._stream("GET", f"/jobs/{job_id}/outputs.zip", f"downloading job {job_id}'s outputs", params) as r:
                with open(archive, "wb") as f:
                    for chunk in r.iter_bytes(1 << 20):
                        f.write(chunk)
            written: list[Path] = []
            with zipfile.ZipFile(archive) as z, atomic_dir(dest) as out:
                for info in z.infolist():
                    if info.is_dir():
                        continue
                    name = _upload_name(info.filename)
                    if name is None:
                        raise ServiceError(f"job {job_id}'s archive names {info.filename!r}, outside its folder")
                    target = out / name
                    target.parent.mkdir(parents=True, exist_ok=True)
                    with z.open(info) as src, open(target, "wb") as dst:
                        while chunk := src.read(1 << 20):
                            dst.write(chunk)
                    written.append(dest / name)
        return sorted(written)

    @contextlib.contextmanager
    def _stream(self, method: str, url: str, what: str, params: dict[str, str]) -> Iterator[httpx.Response]:
        try:
            with self._http.stream(method, url, params=params) as r:
                if r.status_code >= 400:
                    r.read()
                    raise self._refused(r, what)
                yield r
        except httpx.TimeoutException:
            raise ServiceError(f"{self.server}: no answer while {what} (timed out)") from None
        except httpx.TransportError as e:
            raise ServiceError(f"{self.server}: the connection failed while {what}: {e}") from None


def _existing_parent(path: Path) -> Path:
    """The nearest folder of ``path`` (or above) that exists: where a download is staged, on the same disk."""
    p = path.resolve().parent
    while not p.is_dir() and p != p.parent:
        p = p.parent
    return p if os.access(p, os.W_OK) else Path(tempfile.gettempdir())
