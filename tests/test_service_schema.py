"""Property-based requests generated from the service's own OpenAPI document: never a 5xx."""

from __future__ import annotations

import pytest

schemathesis = pytest.importorskip("schemathesis")
from hypothesis import HealthCheck, Phase, given, settings
from schemathesis.checks import not_a_server_error, response_schema_conformance

from forest.service.app import ServiceConfig, create_app
from forest.service.jobs import Limits

from test_service_support import ServerThread

EXAMPLES_PER_OPERATION = 8


def test_no_server_errors_for_any_operation(tmp_path):
    app = create_app(
        ServiceConfig(data_dir=tmp_path / "data", workers=1, dispatch=False, limits=Limits(max_upload_bytes=100_000))
    )
    with ServerThread(app) as srv:
        schema = schemathesis.openapi.from_url(srv.url + "/openapi.json")
        operations = [op.ok() for op in schema.get_all_operations()]
        assert len(operations) >= 12
        # a real job, so that generated requests also reach existing resources
        import httpx

        from test_service_support import tiny_config

        job_id = httpx.post(srv.url + "/jobs", json={"kind": "render", "config": tiny_config()}).json()["id"]
        seen = []
        for op in operations:
            for real_id in (False, True) if "{job_id}" in op.path else (False,):

                @given(case=op.as_strategy())
                @settings(
                    max_examples=EXAMPLES_PER_OPERATION,
                    deadline=None,
                    derandomize=True,
                    database=None,
                    phases=[Phase.explicit, Phase.generate],
                    suppress_health_check=list(HealthCheck),
                )
                def check(case):
                    if real_id:
                        case.path_parameters["job_id"] = job_id
                        if op.path.endswith("/events"):
                            # a finished job's stream ends at once; a live one would run until the job ends
                            httpx.post(f"{srv.url}/jobs/{job_id}/cancel")
                    response = case.call_and_validate(
                        checks=[not_a_server_error, response_schema_conformance], timeout=20
                    )
                    seen.append((op.method.upper(), op.path, response.status_code))

                check()
        # the generated requests reached every operation and got real answers
        assert {(m, p) for m, p, _ in seen} == {(op.method.upper(), op.path) for op in operations}
        assert all(s < 500 for *_, s in seen)
