"""Schemathesis fuzzes every operation of the OpenAPI document: no request may cause a 500."""

from __future__ import annotations

import pytest

schemathesis = pytest.importorskip("schemathesis", reason="pip install schemathesis (in the 'test' extra)")
from hypothesis import HealthCheck, settings  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402

from service.main import create_app  # noqa: E402
from service.settings import Settings  # noqa: E402

# ~16 operations x 25 examples stays under ~20 s on 2 cores; the suite keeps the run bounded.
MAX_EXAMPLES = 25


@pytest.fixture
def api_schema(tmp_path):
    (tmp_path / "replay").mkdir()
    app = create_app(
        Settings(data_dir=tmp_path / "data", replay_root=tmp_path / "replay", workers=0, max_upload_bytes=1_000_000)
    )
    return schemathesis.openapi.from_asgi("/openapi.json", app)


schema = schemathesis.pytest.from_fixture("api_schema")


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
def test_no_server_errors(case):
    response = case.call()
    case.validate_response(response, checks=[not_a_server_error])
