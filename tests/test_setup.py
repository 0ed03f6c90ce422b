"""scripts/setup.sh keeps a torch the venv already has (a user's CUDA build) and installs torch==2.13.0
only into a venv without torch (a wheel on disk first, else the CPU build unless there is an NVIDIA GPU);
the pyproject stamp makes a second run a no-op.

The venv is real (`python -m venv --without-pip`) but its `pip` is a stub that logs each call and, for a
`torch==X` argument, writes torch's metadata as pip would; no network, a second or so per test.
"""
import hashlib
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SETUP = ROOT / "scripts" / "setup.sh"

STUB_PIP = r"""#!/usr/bin/env bash
# logs one call per line: the working directory, then the arguments, tab-separated
printf '%s' "$PWD" >> "$PIP_LOG"; printf '\t%s' "$@" >> "$PIP_LOG"; printf '\n' >> "$PIP_LOG"
# `download` only looks for a wheel: it fails when NO_WHEEL=1 (none on this disk) and installs nothing
for a in "$@"; do [ "$a" = download ] && { [ "${NO_WHEEL:-}" = 1 ] && exit 1; exit 0; }; done
for a in "$@"; do
    case "$a" in
        torch==*) v=${a#torch==}; d="$SITE/torch-$v.dist-info"; mkdir -p "$d"
                  printf 'Metadata-Version: 2.1\nName: torch\nVersion: %s\n' "$v" > "$d/METADATA" ;;
    esac
done
"""

TORCH_REQUIREMENT = re.compile(r"^torch\s*([<>=!~\[;@]|$)")


def make_venv(path: Path, torch_version: str | None) -> dict:
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(path)], check=True)
    probe = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    site = subprocess.run([str(path / "bin" / "python"), "-c", probe],
                          check=True, capture_output=True, text=True).stdout.strip()
    if torch_version:
        d = Path(site) / f"torch-{torch_version}.dist-info"
        d.mkdir(parents=True)
        (d / "METADATA").write_text(f"Metadata-Version: 2.1\nName: torch\nVersion: {torch_version}\n")
    pip = path / "bin" / "pip"
    pip.write_text(STUB_PIP)
    pip.chmod(0o755)
    log = path.parent / "pip.log"
    return {**os.environ, "VENV": str(path), "PIP_LOG": str(log), "SITE": site}


def install_packages(env: dict) -> subprocess.CompletedProcess:
    """The venv/packages step of setup.sh (the libLLVM step is left out: it may call apt-get)."""
    return subprocess.run(["bash", "-c", f"source '{SETUP}' && install_packages"], env=env, capture_output=True,
                          text=True, timeout=60)


def pip_calls(env: dict) -> list[list[str]]:
    log = Path(env["PIP_LOG"])
    return [line.split("\t") for line in log.read_text().splitlines()] if log.exists() else []


def installs_torch(call: list[str]) -> bool:
    """A pip call that names torch as a requirement (not merely through a constraints file)."""
    args = call[1:]
    return "install" in args and any(TORCH_REQUIREMENT.match(a) for a in args)


def constraint_file(call: list[str]) -> Path:
    args = call[1:]
    assert "-c" in args, f"pip call without a constraints file: {args}"
    return Path(args[args.index("-c") + 1])


def test_existing_cuda_torch_is_kept_and_pinned(tmp_path):
    env = make_venv(tmp_path / "venv", "2.5.1+cu121")
    r = install_packages(env)
    assert r.returncode == 0, r.stderr
    calls = pip_calls(env)
    assert calls, "setup.sh never called pip"
    assert not any(installs_torch(c) for c in calls), f"setup.sh installs torch over 2.5.1+cu121: {calls}"
    (project,) = [c for c in calls if "-e" in c]
    assert project[0] == str(ROOT) and project[project.index("-e") + 1] == ".[dev,dask,docs,transient,search]"
    assert constraint_file(project).read_text().split() == ["torch==2.5.1+cu121"]
    assert "keeping the torch 2.5.1+cu121" in r.stdout


def test_cpu_torch_is_installed_only_into_a_venv_without_torch(tmp_path):
    env = make_venv(tmp_path / "venv", None)
    r = install_packages(env)
    assert r.returncode == 0, r.stderr
    calls = pip_calls(env)
    probe, torch_call, project = calls  # a wheel on disk (the stub has one): a plain install takes it
    assert "download" in probe and "--no-index" in probe and not installs_torch(probe)
    assert installs_torch(torch_call) and "torch==2.13.0" in torch_call and "--extra-index-url" not in torch_call
    assert not installs_torch(project) and "-e" in project
    assert constraint_file(project).read_text().split() == ["torch==2.13.0"]


@pytest.mark.parametrize("gpu", [False, True])
def test_without_a_wheel_on_disk_a_cpu_machine_gets_the_cpu_build(tmp_path, gpu):
    """No torch wheel on disk: a machine without an NVIDIA GPU adds PyTorch's CPU index, whose `+cpu` build
    sorts above PyPI's (PyPI's Linux x86-64 torch is a CUDA build of several GB); one with a GPU (a fake
    `nvidia-smi`) installs from the index as it is."""
    if Path("/dev/nvidia0").exists():
        pytest.skip("this machine has an NVIDIA device node: both cases would see a GPU")
    env = make_venv(tmp_path / "venv", None) | {"NO_WHEEL": "1"}
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    if gpu:
        (bin_dir / "nvidia-smi").write_text("#!/usr/bin/env bash\necho 'GPU 0: fake'\n")
        (bin_dir / "nvidia-smi").chmod(0o755)
    path = [d for d in env["PATH"].split(os.pathsep) if not (Path(d) / "nvidia-smi").exists()]
    env["PATH"] = os.pathsep.join([str(bin_dir), *path])
    r = install_packages(env)
    assert r.returncode == 0, r.stderr
    probe, torch_call, project = pip_calls(env)
    assert "download" in probe and "--no-index" in probe and not installs_torch(probe)
    assert installs_torch(torch_call) and "--no-index" not in torch_call
    index = torch_call[torch_call.index("--extra-index-url") + 1] if "--extra-index-url" in torch_call else None
    assert index == (None if gpu else "https://download.pytorch.org/whl/cpu"), torch_call
    assert "-e" in project and constraint_file(project).read_text().split() == ["torch==2.13.0"]


def test_stamp_makes_the_second_run_a_no_op_until_pyproject_changes(tmp_path):
    env = make_venv(tmp_path / "venv", "2.13.0+cpu")
    assert install_packages(env).returncode == 0
    stamp = Path(env["VENV"]) / ".nlosbench-installed"
    assert stamp.read_text().strip() == hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    n = len(pip_calls(env))
    r = install_packages(env)
    assert r.returncode == 0 and "up to date" in r.stdout
    assert len(pip_calls(env)) == n, "second run called pip again"
    stamp.write_text("an older pyproject.toml\n")
    assert install_packages(env).returncode == 0
    assert len(pip_calls(env)) == n + 1 and not installs_torch(pip_calls(env)[-1])


def test_running_the_script_runs_the_install_step(tmp_path):
    """Sourcing defines functions only; `bash scripts/setup.sh` (what `make` runs) must still do the work."""
    from nlosbench.variant import newest_libllvm

    found = newest_libllvm()
    if found is None or found[0] < 16:
        pytest.skip("no libLLVM >= 16 here: setup.sh would try to install one")
    env = make_venv(tmp_path / "venv", "2.6.0+cu124")
    r = subprocess.run(["bash", str(SETUP)], env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    calls = pip_calls(env)
    assert len(calls) == 1 and "-e" in calls[0] and not installs_torch(calls[0])


def test_sourcing_the_script_runs_nothing(tmp_path):
    env = make_venv(tmp_path / "venv", None)
    r = subprocess.run(["bash", "-c", f"source '{SETUP}' && type install_packages >/dev/null"], env=env,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert pip_calls(env) == [] and not (Path(env["VENV"]) / ".nlosbench-installed").exists()
