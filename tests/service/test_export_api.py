"""The result endpoint's exchange formats, from the real server (``wandcal serve`` under uvicorn
on a loopback port): a wand-only job, every format, the pixel origin and unit honoured."""

from __future__ import annotations

import numpy as np

from tests.service.conftest import capture_files, wait_job
from wandcal.capture.formats.dlt import read_dlt_csv
from wandcal.capture.formats.export import FORMAT_NAMES, export
from wandcal.capture.formats.qualisys_vicon import read_qca, read_xcp

MEDIA = {"anipose-toml": "application/toml", "opencv-yaml": "application/x-yaml", "dlt-csv": "text/csv",
         "qca": "application/xml", "xcp": "application/xml"}


def test_every_format_and_the_dlt_origin_over_http(make_server, small_capture):
    folder, _ = small_capture
    server = make_server(workers=1).start()
    with server.client() as c:
        capture = c.post("/captures", files=capture_files(folder)).json()
        job = c.post("/jobs", json={"capture_id": capture["id"], "options": {"use_static": False}}).json()
        job = wait_job(c, job["id"])
        assert job["state"] == "done", job["error"]
        result = job["result"]
        assert result["world"]["frame"] == "wand_volume"
        url = f"/jobs/{job['id']}/result"
        got = {}
        for fmt in FORMAT_NAMES:
            r = c.get(url, params={"format": fmt})
            assert r.status_code == 200, (fmt, r.text)
            assert r.headers["content-type"].startswith(MEDIA[fmt])
            # the same text the command line writes from the same document
            assert r.text == export(result, fmt, None)
            got[fmt] = r.text
        sizes = [(cam["width"], cam["height"]) for cam in result["cameras"]]
        top = c.get(url, params={"format": "dlt-csv", "origin": "top-left", "unit": "mm"})
        assert top.status_code == 200 and top.text != got["dlt-csv"]
        for pc in (read_dlt_csv(got["dlt-csv"], sizes), read_dlt_csv(top.text, sizes, origin="top-left", unit="mm"),
                   read_qca(got["qca"]), read_xcp(got["xcp"])):
            np.testing.assert_allclose(pc.t, [cam["t"] for cam in result["cameras"]], atol=1e-9)
            np.testing.assert_allclose(pc.R, [cam["R"] for cam in result["cameras"]], atol=1e-9)
        for params, words in [({"format": "qca", "unit": "m"}, "qca writes lengths in mm only"),
                              ({"format": "anipose-toml", "origin": "bottom-left"}, "top-left only"),
                              ({"format": "json", "origin": "bottom-left"}, "wandcal-result/1 as written"),
                              ({"format": "dlt-csv", "origin": "centre"}, "origin")]:
            r = c.get(url, params=params)
            assert r.status_code == 422, (params, r.text)
            assert words in r.json()["detail"], (params, r.text)
