"""The automatic variant choice takes the GPU only where forest_path passed its self-check there.

CPU only: the GPU and the check's child are faked (``fake_gpu`` in conftest.py); the time
bound, the crash handling and the process-group kill are proved with real child processes
that sleep, abort or fork, and the real child renders the check's scene in ``llvm_ad_rgb``.
"""

from __future__ import annotations

import functools
import importlib.metadata
import json
import os
import re
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import selfcheck_image

import forest.render.variant as variant
from forest import runtime
from forest.config import parse_config
from forest.errors import ForestError
from forest.render import choose_variant, selfcheck
from forest.render.selfcheck import SelfCheckError

REAL_LAUNCH = selfcheck.launch
FORCE = "force the GPU with --variant cuda_ad_rgb"
MINIMAL = '[terrain]\nflat = {}\n[[species]]\nmodel = "broadleaf"\npercent = 50\n'


def stored(fake_gpu) -> dict:
    return json.loads((fake_gpu.cache / selfcheck.CACHE_NAME).read_text())["checks"]


def forget(monkeypatch) -> None:
    """A new process: nothing remembered but the file."""
    monkeypatch.setattr(selfcheck, "_memo", {})


def test_a_gpu_that_passes_renders_and_its_result_is_stored_and_reused(fake_gpu, monkeypatch):
    v, why = choose_variant(130_000)
    assert v == "cuda_ad_rgb" and why == "GPU found and its self-check passed: forest_path on the GPU (130,000 trees)"
    assert fake_gpu.calls == [("cuda_ad_rgb", selfcheck.TIME_LIMIT_S)]
    [(name, rec)] = stored(fake_gpu).items()
    key = {
        "gpu": "NVIDIA H100 80GB HBM3",
        "driver": "580.159.04",
        "mitsuba": importlib.metadata.version("mitsuba"),
        "drjit": importlib.metadata.version("drjit"),
    }
    assert json.loads(name) == key and rec["key"] == key and rec["ok"] is True and rec["seconds"] >= 0
    forget(monkeypatch)
    assert choose_variant(10)[0] == "cuda_ad_rgb" and variant.default_jit_variant()[0] == "cuda_ad_rgb"
    assert len(fake_gpu.calls) == 1  # read back from the file, not checked again
    check = selfcheck.cached_check()
    assert check is not None and check.ok and check.cached and "passed" in check.line()


def test_commands_can_tell_when_the_check_is_still_to_run(fake_gpu, monkeypatch):
    assert variant.gpu_check_pending() and not fake_gpu.calls
    choose_variant(10)
    assert not variant.gpu_check_pending()
    forget(monkeypatch)
    assert not variant.gpu_check_pending()  # stored
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")
    assert not variant.gpu_check_pending()  # no GPU: nothing to check


def _sleep_past_the_bound(_monkeypatch):
    time.sleep(0.4)  # the bound is 0.2 s in this case
    return selfcheck_image()


def _raise(reason):
    raise SelfCheckError(reason)


def _with_nan(img):
    img[3, 5, 1] = np.nan
    return img


FAILURES = {
    # name: (what the faked child does, given monkeypatch; what the reason says)
    "slow": (_sleep_past_the_bound, "took 0."),
    "timed out": (lambda _mp: _raise("no image within 60 s (killed; no output): the GPU hung"), "no image within 60 s"),
    "crashed": (lambda _mp: _raise("the check process was killed by SIGSEGV: no output"), "killed by SIGSEGV"),
    "black": (lambda _mp: np.zeros((36, 64, 4)), "the image is black"),
    "NaN": (lambda _mp: _with_nan(selfcheck_image()), "1 of 2304 pixels are not finite"),
    "no trees": (lambda _mp: selfcheck_image(trees=False), "the trees are missing"),
    "rays missed": (lambda _mp: selfcheck_image() * np.array([1, 1, 1, 0.5]), "camera rays hit nothing in 50 %"),
}


@pytest.mark.parametrize("failure", list(FAILURES))
def test_a_gpu_that_fails_its_self_check_is_not_chosen_and_the_reason_says_why(fake_gpu, monkeypatch, failure):
    run, words = FAILURES[failure]
    fake_gpu.outcome = lambda: run(monkeypatch)
    if failure == "slow":
        monkeypatch.setattr(selfcheck, "TIME_LIMIT_S", 0.2)
    v, why = choose_variant(1000)
    assert v == "llvm_ad_rgb", why
    assert why.startswith("GPU self-check failed: ") and words in why, why
    assert why.endswith(f"; using llvm_ad_rgb — {FORCE}"), why
    if failure == "slow":
        assert "over the 0.2 s bound" in why
    [rec] = stored(fake_gpu).values()
    assert rec["ok"] is False and words in rec["reason"]
    forget(monkeypatch)
    fake_gpu.outcome = selfcheck_image  # it would pass now, but the stored failure holds for this key
    assert choose_variant(1000) == (v, why) and len(fake_gpu.calls) == 1
    # look-dev's automatic choice follows the same check
    assert variant.default_jit_variant() == ("llvm_ad_rgb", why)


def test_a_new_driver_or_gpu_checks_again(fake_gpu, monkeypatch):
    assert choose_variant(10)[0] == "cuda_ad_rgb"
    fake_gpu.driver = "590.10"
    fake_gpu.outcome = lambda: _raise("the check process exited with status 1: CUDA_ERROR_UNSUPPORTED_PTX_VERSION")
    v, why = choose_variant(10)
    assert v == "llvm_ad_rgb" and "CUDA_ERROR_UNSUPPORTED_PTX_VERSION" in why and len(fake_gpu.calls) == 2
    assert {json.loads(k)["driver"]: r["ok"] for k, r in stored(fake_gpu).items()} == {
        "580.159.04": True,
        "590.10": False,
    }
    forget(monkeypatch)
    fake_gpu.driver = "580.159.04"  # back to the driver that passed: its result is still there
    assert choose_variant(10)[0] == "cuda_ad_rgb" and len(fake_gpu.calls) == 2
    fake_gpu.name = "NVIDIA L4"  # another GPU with the same driver
    assert choose_variant(10)[0] == "llvm_ad_rgb" and len(fake_gpu.calls) == 3


def test_an_explicit_variant_forces_the_gpu_with_no_self_check(fake_gpu):
    fake_gpu.outcome = lambda: pytest.fail("an explicit variant must not run the self-check")
    assert choose_variant(10, "cuda_ad_rgb") == ("cuda_ad_rgb", "requested")
    assert choose_variant(10, None, "cuda_ad_rgb") == ("cuda_ad_rgb", "[render] variant")
    assert choose_variant(10, "llvm_ad_rgb", "cuda_ad_rgb") == ("llvm_ad_rgb", "requested")
    assert not fake_gpu.calls and not (fake_gpu.cache / selfcheck.CACHE_NAME).exists()


def test_no_gpu_or_a_hidden_one_runs_no_check(fake_gpu, monkeypatch):
    fake_gpu.outcome = lambda: pytest.fail("no GPU: no self-check")
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")  # what a scheduler sets for work given no GPU
    v, why = choose_variant(10)
    assert v == "llvm_ad_rgb" and why.startswith("no GPU: forest_path on the CPU") and "faster than scalar_rgb" in why
    with pytest.raises(ForestError, match=r"variant: cuda_ad_rgb needs an NVIDIA GPU"):
        choose_variant(10, "cuda_ad_rgb")
    for hidden in ("-1", "NoDevFiles", "-1,0"):
        monkeypatch.setenv("CUDA_VISIBLE_DEVICES", hidden)
        assert not runtime.cuda_available() and runtime.gpu_info() is None
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0")
    monkeypatch.setattr(runtime, "nvidia_driver", lambda: False)
    assert choose_variant(10)[0] == "llvm_ad_rgb" and variant.capability()["gpu"] is None
    assert not fake_gpu.calls


def test_without_llvm_a_failed_gpu_falls_back_to_scalar(fake_gpu, monkeypatch):
    monkeypatch.setattr(variant, "find_llvm", lambda: None)
    fake_gpu.outcome = lambda: np.zeros((36, 64, 4))
    v, why = choose_variant(10)
    assert v == "scalar_rgb" and why.startswith("GPU self-check failed: the image is black")
    assert why.endswith(f"; using scalar_rgb — {FORCE}")


def test_lookdev_takes_the_gpu_only_where_it_passed(fake_gpu, monkeypatch):
    from forest.lookdev import resolve_settings

    cfg = parse_config(MINIMAL)
    fake_gpu.outcome = lambda: _raise("no image within 60 s (killed; no output): the GPU hung")
    st = resolve_settings(cfg)
    assert st.variant == "llvm_ad_rgb" and st.variant_reason.startswith("GPU self-check failed: no image within")
    assert resolve_settings(cfg, variant="cuda_ad_rgb").variant == "cuda_ad_rgb"  # forced
    forget(monkeypatch)
    (fake_gpu.cache / selfcheck.CACHE_NAME).unlink()
    fake_gpu.outcome = selfcheck_image
    assert resolve_settings(cfg).variant == "cuda_ad_rgb"
    calls = len(fake_gpu.calls)
    forget(monkeypatch)
    (fake_gpu.cache / selfcheck.CACHE_NAME).unlink()
    assert resolve_settings(cfg, pick_variant=False).variant == "auto" and len(fake_gpu.calls) == calls


def test_an_unwritable_cache_only_means_checking_again(fake_gpu, monkeypatch, tmp_path):
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("FOREST_CACHE_DIR", str(tmp_path / "file" / "below"))
    assert choose_variant(10)[0] == "cuda_ad_rgb" and len(fake_gpu.calls) == 1
    assert choose_variant(10)[0] == "cuda_ad_rgb" and len(fake_gpu.calls) == 1  # remembered by the process


def test_the_cache_folder_defaults_to_the_user_cache(monkeypatch):
    import platformdirs

    monkeypatch.delenv("FOREST_CACHE_DIR", raising=False)
    assert selfcheck.cache_path() == Path(platformdirs.user_cache_path("forest")) / "gpu-selfcheck.json"
    monkeypatch.setenv("FOREST_CACHE_DIR", "/somewhere")
    assert selfcheck.cache_path() == Path("/somewhere/gpu-selfcheck.json")


# -- the real child process: the bound, crashes, the process group ---------------------------------------------


def test_the_time_bound_kills_a_child_that_hangs(fake_gpu, monkeypatch):
    """A child that never ends (as a hung GPU would): the choice falls back after the bound, not later."""
    hang = [sys.executable, "-c", "import time; print('compiling kernels', flush=True); time.sleep(120)"]
    monkeypatch.setattr(selfcheck, "launch", functools.partial(REAL_LAUNCH, command=hang))
    monkeypatch.setattr(selfcheck, "TIME_LIMIT_S", 1.0)
    t0 = time.monotonic()
    v, why = choose_variant(10)
    assert time.monotonic() - t0 < 15
    assert v == "llvm_ad_rgb" and why.startswith(
        "GPU self-check failed: no image within 1 s (killed; compiling kernels)"
    )
    [rec] = stored(fake_gpu).values()
    assert rec["ok"] is False and 1.0 <= rec["seconds"] < 15


def _gone(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] == "Z"


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc")
def test_a_timed_out_child_is_killed_with_its_own_children(tmp_path):
    pidfile = tmp_path / "grandchild.pid"
    code = (
        "import subprocess, sys, time; p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)']);"
        f" open({str(pidfile)!r}, 'w').write(str(p.pid)); time.sleep(120)"
    )
    with pytest.raises(SelfCheckError, match=r"^no image within 1.5 s"):
        REAL_LAUNCH(timeout_s=1.5, command=[sys.executable, "-c", code])
    pid = int(pidfile.read_text())
    deadline = time.monotonic() + 10
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _gone(pid)


@pytest.mark.skipif(not hasattr(__import__("signal"), "SIGALRM"), reason="POSIX alarm")
def test_a_child_whose_parent_is_gone_still_ends_at_its_limit(tmp_path):
    """The child's own alarm: a render that hangs ends at ``--limit`` (plus the grace, 0 here) by itself."""
    import signal
    import subprocess

    code = (
        "import sys, time; from forest.render import selfcheck; selfcheck.ALARM_GRACE_S = 0;"
        " selfcheck.render_check = lambda variant: time.sleep(60);"
        " sys.exit(selfcheck.main(['--limit', '1', sys.argv[1]]))"
    )
    t0 = time.monotonic()
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path / "x.npy")], timeout=60)
    assert run.returncode == -signal.SIGALRM and time.monotonic() - t0 < 30


@pytest.mark.parametrize(
    ("code", "words"),
    [
        ("import os; os.abort()", "the check process was killed by SIGABRT"),
        ("import sys; print('selfcheck: RuntimeError: cuInit failed', file=sys.stderr); sys.exit(1)", "exited with "),
        ("pass", "wrote no image"),
    ],
)
def test_a_child_that_crashes_or_writes_nothing_fails_the_check(code, words):
    with pytest.raises(SelfCheckError, match=words) as e:
        REAL_LAUNCH(timeout_s=60, command=[sys.executable, "-c", code])
    if "cuInit" in code:
        assert e.value.reason == "the check process exited with status 1: RuntimeError: cuInit failed"


def test_a_child_image_comes_back_through_the_file(tmp_path):
    code = "import sys, numpy as np; np.save(sys.argv[1], np.full((3, 4, 4), 0.5))"
    img = REAL_LAUNCH(timeout_s=60, command=[sys.executable, "-c", code, "{out}"])
    assert img.shape == (3, 4, 4) and float(img.mean()) == 0.5


@pytest.mark.skipif(runtime.find_llvm() is None, reason="needs LLVM 19 for llvm_ad_rgb")
def test_the_real_child_renders_the_check_scene_and_it_passes_on_the_cpu():
    """``python -m forest.render.selfcheck`` in llvm_ad_rgb (the same forest_path code as on the GPU): the image the
    GPU's must match in kind — finite, lit, covered, with the trees' leaves."""
    img = REAL_LAUNCH("llvm_ad_rgb", timeout_s=300)
    assert img.shape == (selfcheck.HEIGHT, selfcheck.WIDTH, 4)
    assert selfcheck.judge(img) is None
    assert selfcheck.judge(img[..., :3]) is None  # the coverage is optional


# -- the GPU's description -----------------------------------------------------------------------------------


def fake_nvidia_smi(folder: Path, line: str) -> Path:
    """An ``nvidia-smi`` on PATH that prints ``line`` and records its arguments."""
    folder.mkdir(parents=True, exist_ok=True)
    exe = folder / "nvidia-smi"
    exe.write_text(f"#!/bin/sh\necho \"$@\" >> {folder / 'args'}\necho '{line}'\n")
    exe.chmod(0o755)
    return folder


def test_gpu_info_reads_nvidia_smi_of_the_visible_gpu(monkeypatch, tmp_path):
    folder = fake_nvidia_smi(tmp_path / "bin", "NVIDIA H100 80GB HBM3, 81559, 580.159.04")
    monkeypatch.setenv("PATH", f"{folder}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setattr(runtime, "nvidia_driver", lambda: True)
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "1,0")
    runtime._gpu_info.cache_clear()
    try:
        assert runtime.gpu_info() == runtime.GpuInfo("NVIDIA H100 80GB HBM3", 81559, "580.159.04")
        assert "-i 1" in (folder / "args").read_text()  # the GPU CUDA would use
        assert selfcheck.machine_key()["gpu"] == "NVIDIA H100 80GB HBM3"
        monkeypatch.setenv("PATH", str(tmp_path / "empty"))  # no nvidia-smi: a GPU still, of unknown name
        monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0")
        info = runtime.gpu_info()
        assert info is not None and info.name == runtime.UNKNOWN_GPU and info.memory_mib is None
    finally:
        runtime._gpu_info.cache_clear()


@pytest.mark.parametrize(
    "text",
    [
        "NVRM version: NVIDIA UNIX x86_64 Kernel Module  550.54.15  Tue Mar  5 22:23:56 UTC 2024",
        "NVRM version: NVIDIA UNIX Open Kernel Module for x86_64  580.159.04  Release Build  (dvs-builder@U16)",
    ],
)
def test_the_driver_version_without_nvidia_smi(text):
    assert runtime.proc_driver_version(text) in ("550.54.15", "580.159.04")


def test_llvm_is_looked_up_newest_first_and_never_a_crashing_version(tmp_path, monkeypatch):
    """drjit 1.5 crashes on LLVM 14-16 (fminimum); 19 is preferred, then 18, then 17 (rendered the GPU's image)."""
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(sys, "prefix", str(tmp_path))  # no set-up stamp
    versions = [int(re.search(r"(?:LLVM-|llvm-|\.so\.)(\d+)", p).group(1)) for p in runtime._LLVM_CANDIDATES]
    assert versions == sorted(versions, reverse=True) and min(versions) == 17
    fake = {v: tmp_path / f"libLLVM-{v}.so" for v in (19, 17, 16)}
    monkeypatch.setattr(runtime, "_LLVM_CANDIDATES", tuple(str(fake[v]) for v in (19, 17)))
    assert runtime.find_llvm() is None
    fake[16].touch()  # a crashing version is never picked up
    assert runtime.find_llvm() is None
    fake[17].touch()
    assert runtime.find_llvm() == str(fake[17])
    fake[19].touch()
    assert runtime.find_llvm() == str(fake[19])
