"""Schemathesis fuzzes every operation of the OpenAPI document: no request may cause a 500.

Each operation's strategy is run by Hypothesis directly, not through schemathesis's pytest plugin,
whose use of pytest internals breaks across pytest releases.
"""

from __future__ import annotations

import pytest

schemathesis = pytest.importorskip("schemathesis", reason="pip install schemathesis (in the 'test' extra)")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402

from wandcal.service.main import create_app  # noqa: E402
from wandcal.service.settings import Settings  # noqa: E402

# examples per operation: 25 took 127 s on a slow 2-core box (session 24); the uploads' contents are fuzzed
# further in tests/reliability/test_fuzz_http.py
MAX_EXAMPLES = 10


def test_no_server_errors(tmp_path):
    (tmp_path / "replay").mkdir()
    app = create_app(
        Settings(data_dir=tmp_path / "data", replay_root=tmp_path / "replay", workers=0, max_upload_bytes=1_000_000,
                 allowed_hosts=["testserver"])  # the Host schemathesis's ASGI client sends (DNS-rebinding guard)
    )
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 10  # every route is in the document
    for operation in operations:

        @given(case=operation.as_strategy())
        @settings(max_examples=MAX_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True, database=None)
        def fuzz(case):
            response = case.call()
            case.validate_response(response, checks=[not_a_server_error])

        fuzz()
