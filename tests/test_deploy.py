"""The deployment recipes are checked, not just written: Kubernetes schemas, YAML lint, nginx's own parser."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import REPO

DEPLOY = REPO / "deploy"
MANIFESTS = sorted(p for p in (DEPLOY / "kubernetes").glob("*.yaml") if p.name != "kustomization.yaml")
NGINX = shutil.which("nginx") or "/usr/sbin/nginx"


def tool(name: str) -> str:
    return shutil.which(name) or str(Path(sys.executable).with_name(name))


def validate(*paths: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [tool("kubernetes-validate"), "--strict", "--kubernetes-version", "1.31.0", *map(str, paths)],
        capture_output=True,
        text=True,
    )


def test_kubernetes_manifests_match_the_api_schemas(tmp_path):
    result = validate(*MANIFESTS)
    assert result.returncode == 0, result.stdout + result.stderr
    kinds = {yaml.safe_load(p.read_text())["kind"] for p in MANIFESTS}
    assert kinds == {"Deployment", "Service", "PodDisruptionBudget", "HorizontalPodAutoscaler", "PersistentVolumeClaim"}
    kustomization = yaml.safe_load((DEPLOY / "kubernetes" / "kustomization.yaml").read_text())
    assert sorted(kustomization["resources"]) == sorted(p.name for p in MANIFESTS)
    # The validator does fail: a misspelt field is refused.
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(
        (DEPLOY / "kubernetes" / "deployment.yaml").read_text().replace("readinessProbe", "readynessProbe")
    )
    assert validate(wrong).returncode != 0


def test_the_deployment_runs_hardened_with_probes_and_a_read_only_registry():
    spec = yaml.safe_load((DEPLOY / "kubernetes" / "deployment.yaml").read_text())["spec"]["template"]["spec"]
    (container,) = spec["containers"]
    assert container["livenessProbe"]["httpGet"]["path"] == "/healthz"
    assert container["readinessProbe"]["httpGet"]["path"] == "/readyz"
    assert container["resources"]["requests"] and container["resources"]["limits"]
    assert container["securityContext"]["readOnlyRootFilesystem"] is True
    assert spec["securityContext"]["runAsNonRoot"] is True
    mount = next(m for m in container["volumeMounts"] if m["name"] == "models")
    assert mount["readOnly"] is True and mount["mountPath"] == "/models"
    registry = {e["name"]: e["value"] for e in container["env"]}["RGB2CLOUD_REGISTRY"]
    assert registry == "/models"


def test_yaml_lints_clean():
    config = "{extends: default, rules: {line-length: {max: 120}, document-start: disable, truthy: disable}}"
    files = [*MANIFESTS, DEPLOY / "kubernetes" / "kustomization.yaml", DEPLOY / "compose.yaml"]
    result = subprocess.run([tool("yamllint"), "-d", config, *map(str, files)], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout


def test_compose_puts_replicas_behind_nginx_on_a_read_only_registry():
    compose = yaml.safe_load((DEPLOY / "compose.yaml").read_text())["services"]
    replicas = compose["rgb2cloud"]
    assert replicas["deploy"]["replicas"] >= 2 and replicas["read_only"] is True
    (registry,) = [v for v in replicas["volumes"] if v["target"] == "/models"]
    assert registry["read_only"] is True and (DEPLOY / registry["source"]).resolve() == REPO / "weights"
    for mount in compose["balancer"]["volumes"]:
        assert (DEPLOY / mount["source"]).is_file() and mount["read_only"] is True


def test_nginx_accepts_the_shipped_configuration(tmp_path):
    if not Path(NGINX).is_file():
        pytest.fail("no nginx: `make test` installs Debian's package (apt-get install nginx-light)")
    shutil.copy(DEPLOY / "nginx" / "nginx.conf", tmp_path / "nginx.conf")
    shutil.copy(DEPLOY / "nginx" / "upstream.compose.conf", tmp_path / "upstream.conf")
    text = (tmp_path / "upstream.conf").read_text().replace("rgb2cloud:8000", "127.0.0.1:8000")
    (tmp_path / "upstream.conf").write_text(text)  # Docker's DNS name does not resolve here
    result = subprocess.run(
        [NGINX, "-t", "-p", str(tmp_path), "-c", str(tmp_path / "nginx.conf")], capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
