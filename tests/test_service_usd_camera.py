"""The job service takes a scene whose camera comes from a USD stage (``[camera] usd = "shot.usda"``): the stage is
uploaded as an asset, checked as one self-contained USD layer with a camera, and the job renders through it."""

from __future__ import annotations

import math

import httpx
import OpenImageIO as oiio
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom
from test_usd_camera import usd_matrix

from forest.client import ServiceClient, ServiceError
from forest.service.app import ServiceConfig, create_app

from test_service_support import TINY, ServerThread

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

POSITION, TARGET, FOCAL_MM, APERTURE_MM = (25.0, 45.0, -140.0), (0.0, 0.0, 0.0), 35.0, 36.0


def author_camera(path) -> None:
    """A still camera at :data:`POSITION` looking at :data:`TARGET`, a 35 mm lens on a 36 mm aperture (pxr alone)."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    cam = UsdGeom.Camera.Define(stage, "/shot/cam")
    cam.AddTransformOp().Set(usd_matrix(POSITION, TARGET))
    cam.CreateHorizontalApertureAttr(APERTURE_MM)
    cam.CreateVerticalApertureAttr(24.0)
    cam.CreateFocalLengthAttr(FOCAL_MM)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.1, 5000.0))
    stage.GetRootLayer().Save()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("usd-data")
    with ServerThread(create_app(ServiceConfig(data_dir=data, workers=1, seed_examples=False))) as srv:
        yield srv


def test_a_job_renders_through_its_uploaded_usd_camera(server, tmp_path):
    folder = tmp_path / "shot"
    folder.mkdir()
    author_camera(folder / "shot.usda")
    head, _, rest = TINY.format(count=80).partition("[camera]")
    render = rest[rest.index("[render]") :]
    (folder / "scene.toml").write_text(head + '[camera]\nusd = "shot.usda"\n' + render)
    with ServiceClient(server.url) as client:
        job = client.submit_scene(folder / "scene.toml")
        client.wait(job["id"], interval=0.1)
        paths = client.download(job["id"], tmp_path / "out", ext="exr")
    with httpx.Client(base_url=server.url) as c:
        assert [(a["name"], a["kind"]) for a in c.get("/assets").json()] == [("shot.usda", "usd")]
    spec = oiio.ImageInput.open(str(paths[0])).spec()
    position = [float(x) for x in spec.getattribute("forest:camera_position").split(",")]
    assert position == pytest.approx(POSITION, abs=1e-3)
    fov = math.degrees(2.0 * math.atan(APERTURE_MM / (2.0 * FOCAL_MM)))
    assert float(spec.getattribute("forest:fov")) == pytest.approx(fov, abs=1e-3)


def test_a_usd_upload_must_be_one_layer_with_a_camera(server, tmp_path):
    junk = tmp_path / "junk.usda"
    junk.write_text("#usda 1.0\nthis is not a layer {\n")
    outside = tmp_path / "outside.usda"
    author_camera(outside)
    layer = Sdf.Layer.FindOrOpen(str(outside))
    layer.subLayerPaths.append("/etc/hosts.usda")  # a stage that would open a file on the server
    layer.Save()
    empty = tmp_path / "empty.usda"
    stage = Usd.Stage.CreateNew(str(empty))
    UsdGeom.Xform.Define(stage, "/shot")  # a layer, but no camera in it
    stage.GetRootLayer().Save()
    with ServiceClient(server.url) as client:
        for path, status, words in (
            (junk, 415, "not a USD layer"),
            (outside, 422, "names other files (/etc/hosts.usda)"),
            (empty, 422, "has no camera"),
        ):
            with pytest.raises(ServiceError) as e:
                client.upload(path, f"bad/{path.name}")
            assert e.value.status == status and words in str(e.value), str(e.value)
