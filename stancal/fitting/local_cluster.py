"""The local Dask cluster a FitRunner starts when given no scheduler: a
scheduler and single-threaded workers as fresh ``dask spec`` processes
(distributed's SubprocessCluster), with every wait bounded.

distributed's SubprocessScheduler gives its scheduler 30 s to write its
address; when that passes, it reads the scheduler's stderr to the end, which
never comes while the scheduler lives. On a loaded machine (load average 20)
a scheduler that imports stancal took 54 s, and the command hung for an
hour. Here the scheduler has START_TIMEOUT_S, and a start that runs out
kills it and says so; so do workers that never join.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from distributed.deploy.spec import SpecCluster
from distributed.deploy.subprocess import SubprocessScheduler, SubprocessWorker

# stanc has as long on a busy machine (backends.pystan_compile.STANC_TIMEOUT_S)
START_TIMEOUT_S = 300.0
# what distributed's start may take beyond its own deadline before it is stopped
GRACE_S = 5.0


class PatientScheduler(SubprocessScheduler):
    """distributed's scheduler process, given ``timeout`` seconds to start;
    past them it is killed and a RuntimeError names the wait."""

    def __init__(self, scheduler_kwargs: dict | None = None, timeout: float = START_TIMEOUT_S) -> None:
        super().__init__(scheduler_kwargs, timeout)

    async def _start(self) -> None:
        try:  # a scheduler that exited says so itself (distributed's RuntimeError, with its exit code)
            await asyncio.wait_for(super()._start(), self.timeout + GRACE_S)
        except TimeoutError:
            if self.process is not None and self.process.returncode is None:
                self.process.kill()
                await self.process.wait()
            raise RuntimeError(f"the Dask scheduler did not start within {self.timeout:.0f} s "
                               "(is the machine overloaded?)") from None


def local_cluster(workers: int, scheduler_kwargs: dict[str, Any], worker_kwargs: dict[str, Any]) -> SpecCluster:
    """A scheduler and ``workers`` single-threaded plain Workers (no nanny:
    the scheduler reruns a lost worker's fits elsewhere), on 127.0.0.1 with
    a dashboard on a free port, as SubprocessCluster builds them."""
    host = "127.0.0.1"
    # distributed logs each process's full command line at INFO, past SpecCluster's silence_logs:
    # noise in a user's terminal (the dashboard and worker count are said by stancal)
    logging.getLogger("distributed.deploy.subprocess").setLevel(logging.WARNING)
    scheduler = {"cls": PatientScheduler, "options": {"scheduler_kwargs": {
        "host": host, "port": 0, "dashboard": True, "dashboard_address": ":0", **scheduler_kwargs}}}
    worker = {"cls": SubprocessWorker, "options": {"worker_class": "distributed.Worker", "worker_kwargs": {
        "host": host, "nthreads": 1, "silence_logs": logging.WARN, **worker_kwargs}}}
    return SpecCluster(workers=dict.fromkeys(range(workers), worker), scheduler=scheduler, worker=worker,
                       name="stancal", silence_logs=logging.WARN)
