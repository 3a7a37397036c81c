"""Any image, any query: a result or a 4xx JSON error that says why, never a 5xx.

Hypothesis drives the live service (the bundled default model under uvicorn) with random
sizes from 1x1 up, slivers 4000 px long and 1 px thin, every Pillow mode, six formats,
EXIF orientations and focal lengths, and query parameters including intrinsics that are
absurd but finite. The run is bounded (``EXAMPLES``, derandomized) and counted.
"""

from __future__ import annotations

import io
from collections import Counter

import httpx
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import ExifTags, Image, ImageOps
from plyfile import PlyData

from harness.service import BUNDLED_REGISTRY, running_service

EXAMPLES = 200
MODES = ["RGB", "L", "LA", "RGBA", "P", "CMYK", "I;16", "I", "F", "1"]
FORMATS = ["PNG", "JPEG", "WEBP", "GIF", "TIFF", "BMP"]
SIZES = st.one_of(
    st.tuples(st.integers(1, 40), st.integers(1, 40)),  # tiny
    st.tuples(st.integers(1, 3), st.integers(1, 4000)),  # slivers, both ways
    st.tuples(st.integers(1, 4000), st.integers(1, 3)),
    st.tuples(st.integers(40, 800), st.integers(40, 800)),  # ordinary photos, any aspect
)
ANY_FLOAT = st.floats(allow_nan=False, allow_infinity=False)
QUERY = st.fixed_dictionaries(
    {},
    optional={
        "fx": st.one_of(ANY_FLOAT, st.floats(1e-3, 1e5)),
        "fy": st.one_of(ANY_FLOAT, st.floats(1e-3, 1e5)),
        "cx": st.one_of(ANY_FLOAT, st.sampled_from([-1e12, -1.0, 0.0, 1e12])),
        "cy": ANY_FLOAT,
        "stride": st.integers(-2, 80),
        "min_depth": st.floats(-1, 20, allow_nan=False),
        "max_depth": st.floats(-1, 200, allow_nan=False),
        "format": st.sampled_from(["png16", "colormap", "jpeg"]),
        "model": st.sampled_from(["rgb2cloud-7scenes", "rgb2cloud-7scenes:0.8.0", "nope", "nope:1.0.0", "a b"]),
    },
)
EXIF = st.fixed_dictionaries(
    {"orientation": st.integers(0, 9)},
    optional={"f35": st.integers(0, 3000), "focal_mm": st.floats(0, 1000), "plane_res": st.floats(0, 1e6)},
)


def encode(size: tuple[int, int], mode: str, fmt: str, exif: dict, seed: int) -> bytes:
    """A noise photo of ``size`` in ``mode``, saved as ``fmt`` with the EXIF asked for where the format allows."""
    width, height = size
    rgb = np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)
    image = Image.fromarray(rgb)
    image = image.convert("L").convert(mode) if mode in ("I;16", "I", "F") else image.convert(mode)
    tags = Image.Exif()
    tags[ExifTags.Base.Orientation] = exif["orientation"]
    ifd = tags.get_ifd(ExifTags.IFD.Exif)
    if "f35" in exif:
        ifd[ExifTags.Base.FocalLengthIn35mmFilm] = exif["f35"]
    if "focal_mm" in exif:
        ifd[ExifTags.Base.FocalLength] = exif["focal_mm"]
    if "plane_res" in exif:
        ifd[ExifTags.Base.FocalPlaneXResolution] = ifd[ExifTags.Base.FocalPlaneYResolution] = exif["plane_res"]
    buffer = io.BytesIO()
    try:
        image.save(buffer, format=fmt, **({"exif": tags} if fmt in ("JPEG", "PNG", "WEBP", "TIFF") else {}))
    except (OSError, ValueError, KeyError, TypeError):  # a mode this format cannot hold: its RGB instead
        buffer = io.BytesIO()
        image.convert("RGB").save(buffer, format=fmt)
    return buffer.getvalue()


@pytest.fixture(scope="module")
def service():
    with running_service(bundled_registry=BUNDLED_REGISTRY, model="rgb2cloud-7scenes", threads="2") as running:
        yield running.url


@pytest.mark.slow
def test_any_image_and_query_gets_a_result_or_a_4xx_never_a_5xx(service):
    outcomes: Counter[str] = Counter()

    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(
        route=st.sampled_from(["/depth", "/pointcloud"]),
        size=SIZES,
        mode=st.sampled_from(MODES),
        fmt=st.sampled_from(FORMATS),
        exif=EXIF,
        query=QUERY,
        seed=st.integers(0, 2**16),
    )
    def one_request(route, size, mode, fmt, exif, query, seed):
        data = encode(size, mode, fmt, exif, seed)
        r = httpx.post(f"{service}{route}", files={"image": ("photo", data)}, params=query, timeout=120)
        outcomes[str(r.status_code)] += 1
        assert r.status_code < 500, (route, size, mode, fmt, exif, query, r.status_code, r.text[:300])
        if r.status_code >= 400:
            assert r.headers["content-type"].startswith("application/json") and r.json()["detail"], r.text
            return
        with Image.open(io.BytesIO(data)) as sent:
            upright = ImageOps.exif_transpose(sent).size
        if route == "/depth":
            with Image.open(io.BytesIO(r.content)) as depth:
                assert depth.size == upright
        else:
            vertex = PlyData.read(io.BytesIO(r.content))["vertex"]
            assert vertex.count == int(r.headers["x-point-count"])
            if vertex.count:
                assert all(np.isfinite(vertex[axis]).all() for axis in ("x", "y", "z"))

    one_request()
    total = sum(outcomes.values())
    print(f"\n{total} examples: " + ", ".join(f"{status}: {n}" for status, n in sorted(outcomes.items())))
    assert total >= EXAMPLES and not any(status.startswith("5") for status in outcomes)
    assert outcomes["200"] >= total // 4  # most of the space is valid: the run is not all refusals
    assert httpx.get(f"{service}/readyz", timeout=5).status_code == 200
