"""search.cpus (garage_exp/search/cpus.py): a worker kept on chosen CPUs with its threads and the processes it
started; a setting that names no CPU of this machine is one line naming search.cpus."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from garage_exp.core.errors import GarageError
from garage_exp.search import cpus

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="Linux only")


def test_a_cpu_list_is_read_as_linux_writes_one():
    first = min(os.sched_getaffinity(0))
    assert cpus.parse(None) is None and cpus.parse("none") is None
    assert cpus.parse(first) == {first} and cpus.parse(str(first)) == {first}
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) > 1 and allowed[1] == allowed[0] + 1:
        assert cpus.parse(f"{allowed[0]}-{allowed[1]}") == set(allowed[:2])
        assert cpus.parse(f"{allowed[1]},{allowed[0]}") == set(allowed[:2])


@pytest.mark.parametrize("value, words", [("x1", "is not a CPU list"), ("2-1", "is not a CPU list"),
                                          ("-1", "is not a CPU list"), ("4096", "is not one this process may use")])
def test_a_setting_that_names_no_cpu_here_is_refused_naming_search_cpus(value, words):
    with pytest.raises(GarageError, match=words) as caught:
        cpus.parse(value)
    assert caught.value.where == "search.cpus"


def test_pinning_keeps_every_thread_and_child_process_on_the_cpus_then_what_they_start():
    """Run in a child interpreter (pinning this test process would slow the rest of the suite): its thread made
    before, its child process made before (and that one's own child) and a thread made after all end up on the
    one CPU."""
    cpu = max(os.sched_getaffinity(0))
    code = f"""
import os, subprocess, sys, threading, time
from garage_exp.search import cpus
stop = threading.Event()
before = threading.Thread(target=stop.wait); before.start()
child = subprocess.Popen([sys.executable, "-c", "import subprocess, sys; subprocess.run([sys.executable, '-c', 'import time; time.sleep(30)'])"])
time.sleep(1.0)
pinned = cpus.pin({{{cpu}}})
after = threading.Thread(target=stop.wait); after.start()
tasks = [(pid, int(t)) for pid in pinned for t in os.listdir(f"/proc/{{pid}}/task")]
masks = {{tid: sorted(os.sched_getaffinity(tid)) for _, tid in tasks}}
print(len(pinned), len(masks), all(m == [{cpu}] for m in masks.values()), sorted(os.sched_getaffinity(after.native_id)))
stop.set(); child.kill()
for pid in pinned[1:]:
    try: os.kill(pid, 9)
    except OSError: pass
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert out.returncode == 0, out.stderr[-2000:]
    processes, threads, all_pinned, after = out.stdout.split(maxsplit=3)
    assert int(processes) == 3  # itself, its child and that one's child
    assert int(threads) >= 4  # the main thread and the one made before, and each child's
    assert all_pinned == "True" and after.strip() == f"[{cpu}]"


def test_the_search_keeps_its_worker_on_the_cpus_its_config_names(monkeypatch, capsys):
    """sweep.keep_on_cpus (called when the search's multirun starts, before its checks load the detector): the
    config's search.cpus parsed and pinned, a line saying so; nothing pinned without the setting."""
    from omegaconf import OmegaConf

    from garage_exp.search import sweep

    pinned = []
    monkeypatch.setattr(cpus, "pin", lambda wanted: pinned.append(wanted) or ([os.getpid()] if wanted else []))
    cpu = max(os.sched_getaffinity(0))
    sweep.keep_on_cpus(OmegaConf.create({"search": {"cpus": str(cpu)}}))
    assert pinned == [{cpu}] and f"kept on CPU {cpu}" in capsys.readouterr().out
    sweep.keep_on_cpus(OmegaConf.create({"search": {"cpus": None}}))
    assert pinned[-1] is None and capsys.readouterr().out == ""
