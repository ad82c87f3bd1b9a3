"""``saarcor sweep --cluster slurm`` through a real SLURM scheduler: the one-node cluster of
``scripts/slurm-local.sh`` (slurmctld, slurmd, munge on this machine), dask-jobqueue's
``SLURMCluster`` submitting its workers with ``sbatch``. Skipped only where SLURM is not
installed (``make setup`` installs it as root where apt-get works) or its daemons cannot start."""
import csv
import fcntl
import os
import re
import shutil
import subprocess
import tempfile
import time

import pytest

from saarcor import sweep

from .conftest import ROOT

SCRIPT = ROOT / "scripts/slurm-local.sh"
TINY_SPEC = ROOT / "scenes/sweeps/tiny.toml"
SLURM_TOOLS = ("slurmctld", "slurmd", "sbatch", "squeue", "scontrol", "munged")
# measures that differ between two runs of the same point: wall times and whether the kd-tree
# came from the cache (the first run builds it)
VARYING = re.compile(r"seconds|rays_per_second|from_cache")


def script(*args, env=None):
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True,
                          timeout=120, env=env)


@pytest.fixture(scope="module")
def slurm():
    """``SLURM_CONF`` of a running one-node cluster: the one already running, else one started
    here and stopped (jobs cancelled, daemons ended) after the tests."""
    missing = [t for t in SLURM_TOOLS if shutil.which(t) is None]
    if missing:
        pytest.skip(f"SLURM not installed (no {', '.join(missing)}): make setup installs "
                    "slurmctld, slurmd, slurm-client and munge as root where apt-get works")
    env = dict(os.environ)
    # one test run at a time uses the cluster: another run on this machine would stop it
    lock = open(tempfile.gettempdir() + "/saarcor-slurm-test.lock", "w")
    fcntl.flock(lock, fcntl.LOCK_EX)
    started = script("status", env=env).returncode != 0
    if started:
        r = script("start", env=env)
        if r.returncode != 0:
            script("stop", env=env)
            lock.close()
            pytest.skip(f"the one-node SLURM cluster did not start: {r.stdout}{r.stderr}")
    conf = script("env", env=env).stdout.strip().partition("SLURM_CONF=")[2]
    try:
        yield conf
    finally:
        try:
            if started:
                r = script("stop", env=env)
                assert r.returncode == 0, r.stdout + r.stderr
        finally:
            lock.close()


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def scontrol_job(job_id, env):
    """SLURM's own record of a job: ``scontrol show job`` as a dict."""
    out = subprocess.run(["scontrol", "-o", "show", "job", str(job_id)], capture_output=True,
                         text=True, env=env, timeout=30, check=True).stdout
    return dict(f.split("=", 1) for f in out.split() if "=" in f)


def test_sweep_on_slurm_equals_local(tmp_path, slurm, kd_cache, monkeypatch, capsys):
    """The tiny sweep (two golden-model points) with two workers submitted as SLURM batch jobs
    gives the same table as with the default local cluster; each worker ran in a SLURM job
    (its environment has SLURM_JOB_ID; scontrol knows the job as dask-worker on this node),
    and no job is left once the sweep ends."""
    monkeypatch.setenv("SLURM_CONF", slurm)
    env = dict(os.environ)
    local, on_slurm = tmp_path / "local", tmp_path / "slurm"
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    common = [TINY_SPEC, "--kd-cache", kd_cache, "--workers", 2, "--quiet"]
    rc = sweep.main([str(a) for a in common + ["--out", local / "out", "--cache",
                                              local / "cache"]])
    text = capsys.readouterr().out
    assert rc == 0 and "2 points, 0 cached, 2 computed, 0 failed" in text, text

    t0 = time.perf_counter()
    rc = sweep.main([str(a) for a in common + [
        "--out", on_slurm / "out", "--cache", on_slurm / "cache", "--cluster", "slurm",
        "--cluster-option", "cores=1", "--cluster-option", "memory=4GB",
        "--cluster-option", "walltime=00:10:00", "--cluster-option", "interface=lo",
        "--cluster-option", f"log_directory={tmp_path / 'logs'}",
        "--cluster-option", 'scheduler_options={dashboard_address = ":0"}',
        # the job script that starts the worker records its environment
        "--cluster-option", f"job_script_prologue=['env > {jobs}/env-$SLURM_JOB_ID']"]])
    seconds = time.perf_counter() - t0
    text = capsys.readouterr().out
    assert rc == 0 and "2 points, 0 cached, 2 computed, 0 failed" in text, text

    # the workers ran as SLURM jobs of this cluster
    envs = {p.name.removeprefix("env-"): dict(line.split("=", 1) for line in
                                              p.read_text().splitlines() if "=" in line)
            for p in jobs.glob("env-*")}
    assert 1 <= len(envs) <= 2, envs.keys()
    squeue = ""
    for job_id, job_env in envs.items():
        assert job_id.isdigit() and job_env["SLURM_JOB_ID"] == job_id
        assert job_env["SLURM_JOB_NAME"] == "dask-worker"
        assert (tmp_path / "logs" / f"dask-worker-{job_id}.err").is_file()
        # the sweep's end cancels the worker jobs: none is left running or pending
        for _ in range(100):
            rec = scontrol_job(job_id, env)
            squeue = subprocess.run(["squeue", "-h", "-j", job_id, "-t", "PD,R,CG", "-o", "%i"],
                                    capture_output=True, text=True, env=env).stdout.strip()
            if rec["JobState"] not in ("PENDING", "RUNNING", "COMPLETING") and not squeue:
                break
            time.sleep(0.2)
        assert rec["JobName"] == "dask-worker" and rec["BatchFlag"] == "1", rec
        assert rec["NodeList"] == job_env["SLURMD_NODENAME"] != "", rec
        assert rec["JobState"] in ("CANCELLED", "COMPLETED"), rec
        assert squeue == "", f"job {job_id} still queued after the sweep"

    # the same table, apart from wall times
    a, b = read_csv(local / "out/results.csv"), read_csv(on_slurm / "out/results.csv")
    assert len(a) == len(b) == 2 and list(a[0]) == list(b[0])
    compared = [c for c in a[0] if not VARYING.search(c)]
    assert {"key", "kd_max_depth", "counters.trav_ops", "counters.int_ops", "rays_total",
            "kdtree.nodes"} <= set(compared)
    for ra, rb in zip(a, b):
        assert {c: ra[c] for c in compared} == {c: rb[c] for c in compared}
    assert a[0]["counters.trav_ops"] != a[1]["counters.trav_ops"]     # two distinct points
    assert {r["status"] for r in b} == {"ok"}
    print(f"slurm sweep: {seconds:.1f} s")
