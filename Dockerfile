# The serving image: slim Python, the contract and the service only (no torch), the bundled model.
# Mount your own registry (what fit publishes) at /models; the bundled models are served beside it.
ARG BASE=python:3.11-slim
FROM ${BASE}

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    RGB2CLOUD_HOST=0.0.0.0 \
    RGB2CLOUD_PORT=8000 \
    RGB2CLOUD_REGISTRY=/models \
    RGB2CLOUD_BUNDLED_REGISTRY=weights \
    RGB2CLOUD_MODEL=rgb2cloud-7scenes

WORKDIR /srv/rgb2cloud
RUN groupadd --system --gid 10001 rgb2cloud \
    && useradd --system --uid 10001 --gid rgb2cloud --no-create-home rgb2cloud

COPY pyproject.toml README.md ./
COPY contract ./contract
COPY app ./app
# OpenVINO runs ONNX graphs on the CPU: its GPU and NPU plugins (with the GPU's tuning cache) and its
# other frontends are never loaded.
RUN pip install --no-cache-dir . \
    && ov="$(python -c 'import openvino; print(openvino.__path__[0])')/libs" \
    && rm "$ov"/libopenvino_intel_gpu_plugin.so "$ov"/libopenvino_intel_npu_plugin.so "$ov"/cache.json \
    && rm "$ov"/libopenvino_*tensorflow*_frontend.so.* "$ov"/libopenvino_paddle_frontend.so.* \
        "$ov"/libopenvino_pytorch_frontend.so.* "$ov"/libopenvino_jax_frontend.so.* "$ov"/libopenvino_gguf_frontend.so.*

COPY weights ./weights

USER 10001:10001
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:%s/readyz' % os.environ['RGB2CLOUD_PORT'], timeout=4)"]
CMD ["python", "-m", "app"]
