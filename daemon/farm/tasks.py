"""Repair and slicing as Celery tasks on the farm's compute queue.

The task is at-least-once (``acks_late``: the message is acknowledged only when the
task has finished, ``reject_on_worker_lost``; a worker killed mid-task leaves its message
unacknowledged, and Redis hands it to another worker once ``visibility_timeout``,
``[farm] task_timeout``, has passed) and idempotent: its output is keyed by (input
hash, ε, profile hash, printer) in the artefact store, written atomically, and a task
that finds its key done returns it at once. Only keys and small reports travel
through the broker; the files stay in the artefact store.

The task runs repair and slicing in child processes exactly as the daemon does
(:func:`daemon.worker.run_task`: time and memory limits, crashes become reasons).
"""

from __future__ import annotations

import logging
import shutil
import tempfile
from pathlib import Path
from typing import Any

from celery import Celery

from daemon.config import Config
from daemon.farm.artefacts import ArtefactStore, prepared_key

log = logging.getLogger("preflight.farm.tasks")

app = Celery("preflight-farm")
PREPARE = "preflight.farm.prepare"

#: The compute node's config, set by :func:`configure` in the worker process.
_NODE: dict[str, Any] = {}


def compute_queue(cfg: Config) -> str:
    return f"pf.{cfg.farm.name}.compute"


def configure(cfg: Config) -> Celery:
    """Point the Celery app at the farm's broker (the producers and the workers)."""
    timeout = cfg.farm.task_timeout
    app.conf.update(
        broker_url=cfg.farm.broker, result_backend=cfg.farm.broker,
        task_acks_late=True, task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1, task_default_queue=compute_queue(cfg),
        task_serializer="json", result_serializer="json", accept_content=["json"],
        result_expires=86400, broker_connection_retry_on_startup=True,
        broker_connection_max_retries=None, worker_hijack_root_logger=False,
        broker_transport_options={
            "visibility_timeout": timeout,
            # sweep for messages of dead workers often enough to honour the timeout
            "unacked_restore_interval": max(1, int(timeout / 10)),
            "unacked_restore_throttle": 1,
            "global_keyprefix": f"pf:{cfg.farm.name}:celery:",
        },
        result_backend_transport_options={"global_keyprefix": f"pf:{cfg.farm.name}:celery:"},
    )
    _NODE["cfg"] = cfg
    return app


def _run(job_name: str, task: str, spec: dict[str, Any], work: Path, cfg: Config) -> Any:
    from daemon.worker import run_task

    limits = cfg.limits
    timeout, memory_mb = {"repair": (limits.repair_timeout, limits.repair_memory_mb),
                          "slice": (limits.slice_timeout, limits.slice_memory_mb)}[task]
    return run_task(task, {**spec, "job_name": job_name}, work_dir=work, timeout=timeout,
                    memory_mb=memory_mb)


def prepare_job(spec: dict[str, Any], cfg: Config) -> dict[str, Any]:
    """Repair and slice ``spec``'s input for its ε and profile, or reuse a finished run.

    Returns ``{"ok": True, "key", "repair_report", "slice_summary", "node"}`` or
    ``{"ok": False, "reason"}`` (the job fails with that reason; not retried).
    """
    from daemon.worker import WorkerCancelled, WorkerFailed

    assert cfg.farm.artefacts is not None
    store = ArtefactStore(cfg.farm.artefacts)
    printer = {k: spec.get(k) for k in ("build_volume", "flavour", "filament_diameter")}
    key = prepared_key(spec["input"], spec["epsilon"], spec["profile"], printer)
    done = store.get_prepared(key)
    if done is not None:
        return {**done, "reused": True}
    work = Path(tempfile.mkdtemp(prefix="farm-", dir=cfg.daemon.state_dir))
    name = spec["name"]
    try:
        repaired, gcode = work / "repaired.stl", work / f"{Path(name).stem}.gcode"
        try:
            report = _run(name, "repair", {
                "in": str(store.input_path(spec["input"])), "out": str(repaired),
                "report": str(work / "repair.report.json"), "epsilon": spec["epsilon"],
                "max_bytes": int(cfg.limits.max_file_mb * 1024 * 1024),
                "max_triangles": cfg.limits.max_triangles, "clean": cfg.repair.clean,
            }, work, cfg)
        except WorkerFailed as e:
            result = {"ok": False, "reason": f"repair failed: {e}"}
        else:
            try:
                out = _run(name, "slice", {
                    "in": str(repaired), "out": str(gcode), "nozzle": spec["epsilon"],
                    "overrides": spec["profile"], **printer,
                }, work, cfg)
            except WorkerFailed as e:
                result = {"ok": False, "reason": f"slicing failed: {e}"}
            else:
                result = {"ok": True, "key": key, "repair_report": report,
                          "slice_summary": (out or {}).get("summary") or {},
                          "node": cfg.farm.node}
        store.put_prepared(key, gcode if result["ok"] else None, result)
        return result
    except WorkerCancelled:
        raise RuntimeError("the compute node is stopping") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)


@app.task(name=PREPARE, acks_late=True, reject_on_worker_lost=True)
def prepare(spec: dict[str, Any]) -> dict[str, Any]:
    cfg = _NODE["cfg"]
    log.info("prepare %s (ε %s) for %s", spec.get("name"), spec.get("epsilon"),
             spec.get("for"))
    return prepare_job(spec, cfg)
