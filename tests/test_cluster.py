"""The study on a Ray cluster, tested as Ray tests itself.

``ray.cluster_utils.Cluster`` starts a head node (no CPU: it runs no run) and two worker nodes of one CPU on
this machine, every one bound to 127.0.0.1, with a Ray folder of their own (another Ray instance on the machine
is neither joined nor disturbed). ``sb3-cic study --address`` runs two fine-tunings across the worker nodes; the
node of one of them is removed after its first checkpoint. Every Ray process the test started is stopped by its
id (``Cluster.shutdown`` kills each node's processes; the workers they started are checked gone).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Iterator

import pytest
import ray
import psutil  # after ray: the copy Ray ships and uses
from ray.cluster_utils import Cluster

from sb3_cic.study.cli import settings_from_args
from sb3_cic.study.driver import run_protocol
from sb3_cic.study.cli import build_parser
from waiting import wait_for

LOCALHOST = "127.0.0.1"
SEEDS = (0, 1)
#: the study of the test (two fine-tunings of 2,000 steps, a checkpoint at the end of the first episode, step 1,000)
STUDY = [
    "--methods", "ddpg", "--domains", "walker", "--tasks", "stand", "--seeds", *map(str, SEEDS),
    "--finetune-steps", "2000", "--hidden-dim", "32", "--batch-size", "32", "--learning-starts", "500",
    "--buffer-size", "10000", "--eval-freq", "1000", "--eval-episodes", "1", "--num-threads", "1",
    "--checkpoint-every", "1000", "--no-progress", "--max-retries", "2",
]


def running(process: psutil.Process) -> bool:
    """Whether ``process`` still runs (a zombie has stopped; psutil tells a reused pid apart)."""
    try:
        return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


class RayProcesses:
    """The processes of a cluster's nodes and those they started, as seen so far (a worker process starts when a
    run does, so :meth:`see` is called again as the study goes on).

    :param cluster: the cluster
    """

    def __init__(self, cluster: Cluster) -> None:
        self.cluster = cluster
        self.seen: dict[int, psutil.Process] = {}

    def see(self) -> None:
        """Add the processes of the nodes still in the cluster and their descendants."""
        for node in self.cluster.list_all_nodes():
            for infos in node.all_processes.values():
                for info in infos:
                    try:
                        process = psutil.Process(info.process.pid)
                        for child in [process, *process.children(recursive=True)]:
                            self.seen.setdefault(child.pid, child)
                    except psutil.NoSuchProcess:
                        pass

    def alive(self) -> list[psutil.Process]:
        """The processes seen that still run."""
        return [process for process in self.seen.values() if running(process)]

    def wait_stopped(self, timeout: float = 30) -> list[psutil.Process]:
        """Wait until every process seen has stopped; return those still running after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while self.alive() and time.monotonic() < deadline:
            time.sleep(0.2)
        return self.alive()


@pytest.fixture
def cluster(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[Cluster, RayProcesses]]:
    """A head node and two worker nodes on 127.0.0.1; at the end, every process seen is stopped by its pid."""
    base = Path(tempfile.mkdtemp(prefix="ray"))  # short: Ray's socket paths must stay under 108 characters
    (base / "ray").mkdir()
    # the address file Cluster writes (ray_current_cluster) and the sessions go here, not into the default Ray
    # folder that another Ray instance of this machine may use
    monkeypatch.setenv("RAY_TMPDIR", str(base))
    # the nodes' workers at the test's niceness, as a local study has them (Ray's 15 starves them behind other work):
    # Ray adds RAY_worker_niceness to the niceness its raylet inherited from this process
    monkeypatch.setenv("RAY_worker_niceness", "0")
    handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    cluster = Cluster(
        initialize_head=True,
        head_node_args={
            "node_ip_address": LOCALHOST, "num_cpus": 0, "include_dashboard": False, "temp_dir": str(base / "ray")
        },
    )
    processes = RayProcesses(cluster)
    try:
        for _ in range(2):
            cluster.add_node(node_ip_address=LOCALHOST, num_cpus=1)
        cluster.wait_for_nodes()
        processes.see()
        yield cluster, processes
    finally:
        processes.see()
        cluster.shutdown()
        for process in processes.wait_stopped():  # left by a failed test: stopped by id
            try:
                process.kill()
            except psutil.NoSuchProcess:
                pass
        shutil.rmtree(base, ignore_errors=True)
        for signum, handler in handlers.items():  # the head node started here installs Ray's own in this process
            signal.signal(signum, handler)


def node_of(cluster: Cluster, pid: int) -> ray._private.node.Node:
    """The worker node whose raylet started the process ``pid``."""
    ancestors = {parent.pid for parent in psutil.Process(pid).parents()}
    nodes = [node for node in cluster.worker_nodes if node.all_processes["raylet"][0].process.pid in ancestors]
    assert len(nodes) == 1, f"process {pid} is not a worker of one node of the cluster"
    return nodes[0]


def read_progress(folder: Path) -> dict:
    """A run folder's ``progress.json`` (empty when there is none)."""
    try:
        return json.loads((folder / "progress.json").read_text())
    except (OSError, ValueError):
        return {}


@pytest.mark.slow  # about 2.5 minutes on two busy cores
@pytest.mark.timeout(0)  # no wall-clock limit: each wait below is bounded by the CPU its processes use (tests/waiting.py)
def test_node_removed_after_first_checkpoint_the_run_resumes_on_another_node(cluster, tmp_path: Path):
    """Remove the node of the first run to checkpoint: Ray retries the run on the other node, where it resumes from
    the checkpoint; the study ends with both runs done once and the evaluations of an uninterrupted study."""
    cluster, processes = cluster
    study = tmp_path / "study"
    folders = {seed: study / "finetune" / "ddpg" / "walker_stand" / f"seed_{seed}" for seed in SEEDS}
    # Ray turns a loopback address into this machine's network address, unless clusters are off (its switch for
    # a cluster confined to one machine): the driver then joins the nodes on 127.0.0.1
    env = {**os.environ, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "OMP_NUM_THREADS": "1", "MUJOCO_GL": "disable"}
    command = [sys.executable, "-m", "sb3_cic.cli", "study", str(study), "--address", cluster.address, *STUDY]
    log = tmp_path / "driver.log"
    with log.open("w") as out:
        driver = subprocess.Popen(command, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        checkpointed = {}

        def a_run_checkpointed() -> bool:
            checkpointed.update({s: read_progress(f) for s, f in folders.items()
                                 if (f / "checkpoint.zip").exists() and read_progress(f).get("checkpoint_step")})
            # and the other run has started (on a loaded machine it may start after the first checkpoint)
            return bool(checkpointed) and all(read_progress(f).get("pid") for f in folders.values())

        wait_for(a_run_checkpointed, "a run's first checkpoint, with the other run started", driver, log.read_text)
        seed, progress = next(iter(checkpointed.items()))
        (rest,) = set(SEEDS) - {seed}
        removed = node_of(cluster, progress["pid"])
        (other,) = cluster.worker_nodes - {removed}
        assert node_of(cluster, read_progress(folders[rest])["pid"]) is other  # one run on each node
        processes.see()
        worker = processes.seen[progress["pid"]]
        cluster.remove_node(removed)
        # the run's worker stops with its node: it trains no further
        wait_for(lambda: not running(worker), "the removed node's worker to stop", driver, log.read_text)
        # the retry: another process, on the other node (free once its own run is done), from the checkpoint
        wait_for(lambda: read_progress(folders[seed]).get("pid", progress["pid"]) != progress["pid"],
                 "Ray's retry of the run on the other node", driver, log.read_text)
        retry = read_progress(folders[seed])
        assert node_of(cluster, retry["pid"]) is other and retry["checkpoint_step"] == progress["checkpoint_step"]
        processes.see()
        assert retry["pid"] in processes.seen  # checked stopped at the end
        wait_for(lambda: driver.poll() is not None, "the study to end", output=log.read_text)
    finally:
        if driver.poll() is None:
            driver.kill()
            driver.wait()
    output = log.read_text()
    assert driver.returncode == 0, output
    assert "2 runs, 2 done, 0 running, 0 failed, 0 pending" in output and "2 runs ran now" in output, output
    results = {s: json.loads((folder / "result.json").read_text()) for s, folder in folders.items()}
    assert results[seed]["resumed_from_step"] == progress["checkpoint_step"] > 0
    assert results[rest]["resumed_from_step"] == 0
    assert not [p for pattern in ("checkpoint*", "progress.json", "error.txt") for p in study.rglob(pattern)]

    settings = settings_from_args(build_parser().parse_args(["-", *STUDY]))
    run_protocol(tmp_path / "uninterrupted", "ddpg", "walker", tasks=["stand"], seeds=SEEDS, settings=settings)
    for s, folder in folders.items():
        expected = tmp_path / "uninterrupted" / folder.relative_to(study)
        assert results[s]["final_return"] == json.loads((expected / "result.json").read_text())["final_return"]
        # every evaluation, each once: the retry went on from the checkpoint, it did not start over
        assert (folder / "eval.csv").read_text() == (expected / "eval.csv").read_text()

    processes.see()
    cluster.shutdown()
    wait_for(lambda: not processes.alive(), "every process of the cluster to stop", output=lambda: str(processes.alive()))
