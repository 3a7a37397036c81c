"""The committed OpenAPI document is the app's own."""

from __future__ import annotations

from conftest import REPO

from app.openapi import DEFAULT_PATH, document


def test_committed_openapi_matches_the_app():
    committed = (REPO / DEFAULT_PATH).read_text()
    assert committed == document(), "openapi/openapi.json is stale: run `python -m app.openapi`"


def test_openapi_documents_the_public_contract():
    import json

    spec = json.loads(document())
    assert {"/depth", "/pointcloud", "/healthz", "/readyz", "/v1/models", "/metrics"} <= set(spec["paths"])
    depth = spec["paths"]["/depth"]["post"]
    assert "image/png" in depth["responses"]["200"]["content"]
    assert {"400", "413", "415", "422", "503"} <= set(depth["responses"])
    names = {p["name"] for p in spec["paths"]["/pointcloud"]["post"]["parameters"]}
    assert {"fx", "fy", "cx", "cy", "stride", "min_depth", "max_depth"} <= names
