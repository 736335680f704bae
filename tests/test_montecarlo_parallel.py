"""Monte Carlo studies across processes: resume after SIGKILL, a run sharded over
4 virtual CPU devices and a two-process `jax.distributed` run all give results
bit-identical to one uninterrupted single-device run.

Each case starts fresh Python processes (each compiles the study anew), so the
study is the small one of `examples/distributed_study.py`.
"""

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import pytest
import xarray as xr

from elasticoop import montecarlo as mc
from elasticoop._cli import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "distributed_study.py"
sys.path.insert(0, str(EXAMPLE.parent))
from distributed_study import make_study  # noqa: E402

N_SAMPLES, T_END, BATCH_WIDTH = 16, 0.2, 4
pytestmark = pytest.mark.slow  # fresh processes, each compiling the study
SUBPROCESS_TIMEOUT = 300  # s, generous: a loaded 2-core machine compiles slowly

CHILD = """
import sys, time
sys.path.insert(0, {examples!r})
from distributed_study import make_study
from elasticoop import montecarlo as mc

mc.run_study(
    make_study({n}, {t_end}), {store!r}, batch_width={width}, chunk_size={chunk},
    progress=False, on_chunk=lambda chunk: time.sleep({pause}),
)
"""


def _env(**extra):
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT)) | extra
    env.pop("XLA_FLAGS", None)
    return env | extra


def _child(store, chunk, pause=0.0):
    code = CHILD.format(
        examples=str(EXAMPLE.parent),
        n=N_SAMPLES,
        t_end=T_END,
        store=str(store),
        width=BATCH_WIDTH,
        chunk=chunk,
        pause=pause,
    )
    return [sys.executable, "-c", code]


@pytest.fixture(scope="module")
def study():
    return make_study(N_SAMPLES, T_END)


@pytest.fixture(scope="module")
def reference(study):
    """One uninterrupted single-device run, in memory, in chunks of 4 samples: those
    of the store the resumed run completes, which thus reuses this run's compiled
    chunk (a chunk size changes no result: tests/test_montecarlo.py)."""
    return mc.run_study(study, chunk_size=4, batch_width=BATCH_WIDTH, progress=False)


def _same(ds, reference):
    assert ds.attrs["complete"] == 1
    xr.testing.assert_identical(ds.drop_attrs(), reference.drop_attrs())


def test_resume_after_sigkill_is_bit_identical(study, reference, tmp_path):
    store = tmp_path / "study"
    child = subprocess.Popen(
        _child(store, chunk=4, pause=1.0), env=_env(), stderr=subprocess.PIPE
    )
    deadline = time.monotonic() + SUBPROCESS_TIMEOUT
    while len(list(store.glob("chunk-*.npz"))) < 2:
        if child.poll() is not None:
            pytest.fail(f"the study ended before it was killed: {child.stderr.read()}")
        assert time.monotonic() < deadline, "no chunk written in time"
        time.sleep(0.02)
    child.send_signal(signal.SIGKILL)
    child.wait()
    child.stderr.close()
    before = set(mc.open_study(store)["sample"].values)
    assert 8 <= len(before) < N_SAMPLES
    ran = []
    ds = mc.run_study(
        study, store, batch_width=BATCH_WIDTH, progress=False, on_chunk=ran.append
    )
    assert ran and all(4 * c not in before for c in ran)  # done chunks not redone
    _same(ds, reference)
    _same(mc.open_study(store), reference)


def test_four_devices_equal_one(reference, tmp_path):
    store = tmp_path / "study"
    subprocess.run(
        _child(store, chunk=8),
        env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=4"),
        check=True,
        timeout=SUBPROCESS_TIMEOUT,
    )
    _same(mc.open_study(store), reference)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_process_distributed_run_equals_local(reference, tmp_path):
    store = tmp_path / "study"
    common = [
        sys.executable,
        str(EXAMPLE),
        f"--store={store}",
        "--num-processes=2",
        f"--coordinator=localhost:{_free_port()}",
        f"--samples={N_SAMPLES}",
        f"--t-end={T_END}",
        f"--batch-width={BATCH_WIDTH}",
        "--chunk-size=8",
    ]
    workers = [
        subprocess.Popen(
            [*common, f"--process-id={k}"],
            env=_env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for k in (0, 1)
    ]
    logs = [w.communicate(timeout=SUBPROCESS_TIMEOUT)[0] for w in workers]
    for w, log in zip(workers, logs):
        assert w.returncode == 0, log
    assert "'n_succeeded': 16" in logs[0]
    _same(mc.open_study(store), reference)


def test_samples_at_rest_sharded_over_two_devices_equal_one(tmp_path):
    # The shipped study, each sample starting at rest in its own closed loop
    # (`[initial] from = "equilibrium"`), over two virtual CPU devices. Old: the
    # samples' rest states were solved in the sharded program, whose solver loop
    # waited forever for the devices (no chunk written after minutes, ~6 % CPU).
    # The run on one device, the reference, is the same command in this process
    # (one CPU device); the run on two is a fresh process, as a user starts it.
    study = ROOT / "elasticoop" / "scenarios" / "beam_lift.study.toml"
    argv = ["montecarlo", str(study), "--samples", "8", "-q"]
    assert len(jax.devices()) == 1
    assert main([*argv, "-o", str(tmp_path / "on-1")]) == 0
    subprocess.run(
        [sys.executable, "-m", "elasticoop", *argv, "-o", str(tmp_path / "on-2")],
        env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=2"),
        check=True,
        timeout=SUBPROCESS_TIMEOUT,
    )
    one, two = (mc.open_study(tmp_path / f"on-{n}") for n in (1, 2))
    assert one.attrs["complete"] == 1
    assert '"initial": "equilibrium"' in one.attrs["study"]
    xr.testing.assert_identical(one.drop_attrs(), two.drop_attrs())
