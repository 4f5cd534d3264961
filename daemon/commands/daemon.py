"""CLI: ``preflight run``, ``preflight status``, ``preflight jobs ...``, ``preflight demo``.

The CLI talks to the running daemon through the SQLite journal: it reads jobs
and the daemon's status row directly, and writes print / requeue / cancel
requests as rows that the daemon polls (every 0.2 s) and answers.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from daemon.commands import fail

CONFIG_HELP = ("TOML config file (default: $PREFLIGHT_CONFIG, else /etc/preflight/preflight.toml, "
               "else built-in defaults)")


def _config_arg(p: argparse.ArgumentParser, *, suppress: bool = False) -> None:
    p.add_argument("--config", "-c", metavar="FILE", help=CONFIG_HELP,
                   default=argparse.SUPPRESS if suppress else None)


def _load(args: argparse.Namespace):
    import os

    from daemon.config import load_config

    path = getattr(args, "config", None) or os.environ.get("PREFLIGHT_CONFIG") or None
    return load_config(path)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("run", help="run the daemon in the foreground",
                              description="Watch the spool folder, repair, slice and print.")
    _config_arg(p)
    p.set_defaults(func=cmd_run)

    p = subparsers.add_parser("status", help="show the running daemon's status")
    _config_arg(p)
    p.add_argument("--json", action="store_true", help="print the status as JSON")
    p.set_defaults(func=cmd_status)

    p = subparsers.add_parser("api-key", help="print the web API key slicers need")
    _config_arg(p)
    p.set_defaults(func=cmd_api_key)

    p = subparsers.add_parser("jobs", help="list, show, print, requeue, cancel, pause, resume "
                                           "or stop jobs")
    _config_arg(p)
    jsub = p.add_subparsers(dest="jobs_command", metavar="ACTION")
    q = jsub.add_parser("list", help="list jobs (newest last)")
    _config_arg(q, suppress=True)
    q.add_argument("--all", action="store_true", help="all jobs, not only the last 50")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_jobs_list)
    q = jsub.add_parser("show", help="show one job with its reports and history")
    _config_arg(q, suppress=True)
    q.add_argument("id", type=int)
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=cmd_jobs_show)
    for action, text in (("print", "print a ready job (when auto_print is off)"),
                         ("requeue", "re-send an interrupted print, or redo a failed/cancelled "
                                     "job"),
                         ("cancel", "cancel a job; a running print stops, parks, cools down "
                                    "and releases the motors (never resumable)"),
                         ("pause", "pause a print: the lines sent finish, then retract and "
                                   "park; the heaters stay on"),
                         ("resume", "resume a paused print where it stopped"),
                         ("stop", "emergency stop: M112 now (the printer must be reset)")):
        q = jsub.add_parser(action, help=text)
        _config_arg(q, suppress=True)
        q.add_argument("id", type=int)
        q.add_argument("--wait", type=float, default=15.0, metavar="S",
                       help="seconds to wait for the daemon's answer (default 15)")
        q.set_defaults(func=cmd_jobs_request, action=action)
    p.set_defaults(func=lambda a, _p=p: (_p.print_help(sys.stderr), 2)[1])

    p = subparsers.add_parser("example-config", help="print the documented example config "
                                                     "(every key, its default and what it does)")
    p.add_argument("--output", "-o", metavar="FILE", help="write it to FILE instead")
    p.set_defaults(func=cmd_example_config)

    p = subparsers.add_parser("demo", help="run the daemon on a temporary spool with the "
                                           "virtual printer and print a shipped broken model")
    p.add_argument("--keep", action="store_true", help="keep the temporary folder")
    p.add_argument("--speedup", type=float, default=None,
                   help="virtual printer speed-up factor")
    p.set_defaults(func=cmd_demo)


# --- run ---------------------------------------------------------------------------------

def cmd_run(args: argparse.Namespace) -> int:
    from daemon.config import ConfigError, check_profile, setup_logging

    try:
        cfg = _load(args)
        check_profile(cfg)
        if cfg.farm.broker:
            from daemon.farm import check_farm_config

            check_farm_config(cfg)
    except ConfigError as e:
        return fail(str(e), 2)
    setup_logging(cfg.daemon.log_level)
    from daemon.service import AlreadyRunning, Daemon

    try:
        daemon = Daemon(cfg)
    except (AlreadyRunning, OSError) as e:
        return fail(_start_error(e))
    return daemon.run()


def _start_error(error: Exception) -> str:
    """Why the daemon could not start, in one line."""
    if isinstance(error, OSError):
        return (f"cannot set up {error.filename or 'the state/spool folders'}: "
                f"{error.strerror}")
    return str(error)


# --- status and jobs ---------------------------------------------------------------------

def _journal(args: argparse.Namespace):
    from daemon.config import ConfigError
    from daemon.journal import Journal

    try:
        cfg = _load(args)
    except ConfigError as e:
        raise SystemExit(fail(str(e), 2)) from None
    if not cfg.journal_path.exists():
        raise SystemExit(fail(f"no journal at {cfg.journal_path}: the daemon has never run with "
                               f"this configuration ({cfg.source})"))
    return cfg, Journal(cfg.journal_path, readonly=True)


def cmd_status(args: argparse.Namespace) -> int:
    from daemon.printlog import format_temperatures
    from daemon.service import Daemon, daemon_alive

    cfg, journal = _journal(args)
    status = journal.get_meta("status")
    alive = daemon_alive(status)
    if status:  # job counts from the journal now, not from the heartbeat (up to 1 s old):
        status["jobs"] = journal.counts()  # status right after `jobs pause` says paused
    key = _api_key(cfg)
    if args.json:
        print(json.dumps({"alive": alive, **(status or {}), "api_key": key}, indent=2))
        return 0 if alive else 3
    if not alive:
        last = (time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(status["heartbeat"]))
                if status else "?")
        print(f"preflight daemon: not running (last seen {last})")
        counts = journal.counts()
        print("jobs: " + (", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "none"))
        if key:
            print(f"web API key: {key}")
        return 3
    since = time.strftime("%H:%M:%S", time.localtime(status["started"]))
    print(f"preflight daemon: running (pid {status['pid']}, since {since}, "
          f"config {status['config']})")
    print(Daemon.status_line(status))
    printer = status.get("printer") or {}
    info = printer.get("info") or {}
    if info:
        bv = info.get("build_volume")
        print(f"printer: {printer.get('port')} - {info.get('firmware')}, nozzle "
              f"{info.get('nozzle_diameter')} mm ({info.get('nozzle_source')}), build volume "
              f"{' x '.join(f'{v:g}' for v in bv) + ' mm' if bv else 'unknown'}"
              + (f" ({info['build_volume_source']})" if bv and info.get("build_volume_source")
                 else ""))
    elif printer.get("message"):
        print(f"printer: {printer.get('port')} - {printer.get('state')}: {printer['message']}")
    printers = status.get("printers") or []
    if len(printers) > 1:
        from daemon.printers import describe_printer

        for entry in printers:
            print(describe_printer(entry))
    temperatures = format_temperatures(printer.get("temperatures"))
    if temperatures:
        print(f"temperatures: {temperatures}")
    print(f"spool: {status['spool']} ({status.get('waiting_files', 0)} file(s) being written)")
    web = status.get("web") or {}
    if web:
        where = web.get("error") or f"{web.get('url')} (listening on {web.get('listen')})"
        print(f"web API: {where}; API key: {key or 'not made yet'}")
    print("jobs: " + (", ".join(f"{v} {k}" for k, v in sorted(status["jobs"].items())) or "none"))
    return 0


def _api_key(cfg) -> str | None:
    from daemon.web.auth import read_key

    try:
        return read_key(cfg.daemon.state_dir)
    except PermissionError:
        return None


def cmd_api_key(args: argparse.Namespace) -> int:
    from daemon.config import ConfigError
    from daemon.web.auth import key_path

    try:
        cfg = _load(args)
    except ConfigError as e:
        return fail(str(e), 2)
    try:
        key = _api_key(cfg)
    except OSError as e:
        return fail(f"cannot read {key_path(cfg.daemon.state_dir)}: {e.strerror}")
    if key is None:
        path = key_path(cfg.daemon.state_dir)
        if path.exists():
            return fail(f"cannot read {path}: run this as the daemon's user (or root)")
        return fail(f"no API key yet: it is made when the daemon first starts ({path})")
    print(key)
    return 0


def _job_line(job) -> str:
    prog = ""
    if job.progress is not None and str(job.state) in ("repairing", "slicing", "printing",
                                                       "paused"):
        prog = f" {100 * job.progress:.0f}%"
    when = time.strftime("%m-%d %H:%M", time.localtime(job.updated))
    reason = f"  {job.reason}" if job.reason and str(job.state) != "done" else ""
    where = f" on {job.printer}" if job.printer not in (None, "printer") else ""
    if job.pinned and job.nozzle:
        where += f" (pinned to a {job.nozzle:g} mm nozzle)"
    return (f"{job.id:>5}  {str(job.state) + prog:<16} {when}  {job.source_name}{where}"
            f"{reason}")


def cmd_jobs_list(args: argparse.Namespace) -> int:
    _, journal = _journal(args)
    jobs = journal.jobs(limit=None if args.all else 50)
    if args.json:
        print(json.dumps([x.to_dict() for x in jobs], indent=2, default=str))
        return 0
    if not jobs:
        print("no jobs")
        return 0
    print(f"{'ID':>5}  {'STATE':<16} {'UPDATED':<11}  FILE")
    for job in jobs:
        print(_job_line(job))
    return 0


def cmd_jobs_show(args: argparse.Namespace) -> int:
    from daemon.report import report_dict, report_text

    _, journal = _journal(args)
    job = journal.get(args.id)
    if job is None:
        return fail(f"there is no job {args.id}")
    history = journal.history(job.id)
    if args.json:
        print(json.dumps(report_dict(job, history), indent=2, default=str))
        return 0
    sys.stdout.write(report_text(job, history))
    if job.outputs:
        for k, v in sorted(job.outputs.items()):
            print(f"  {k}: {v}")
    return 0


def cmd_jobs_request(args: argparse.Namespace) -> int:
    from daemon.service import daemon_alive

    cfg, journal = _journal(args)
    from daemon.journal import Journal

    if journal.get(args.id) is None:
        return fail(f"there is no job {args.id}")
    writer = Journal(cfg.journal_path)
    if args.action in ("pause", "resume", "stop") and not daemon_alive(writer.get_meta("status")):
        # never left to act later: a stale pause or stop would hit the next print
        return fail(f"the daemon is not running; nothing is printing to {args.action}", 3)
    request_id = writer.add_request(args.id, args.action)
    if not daemon_alive(writer.get_meta("status")):
        return fail(f"the daemon is not running; the {args.action} request for job {args.id} "
                     "is recorded and will be carried out when it starts", 3)
    end = time.monotonic() + args.wait
    while time.monotonic() < end:
        answer = writer.request(request_id)
        if answer and answer["handled"]:
            if answer["ok"]:
                print(answer["message"])
                return 0
            return fail(answer["message"])
        time.sleep(0.1)
    return fail(f"the daemon did not answer within {args.wait:g} s; the request stays recorded")


def cmd_example_config(args: argparse.Namespace) -> int:
    from daemon.config_example import example_config

    text = example_config()
    if args.output:
        from repair.io import write_atomic

        write_atomic(args.output, [text.encode()])
    else:
        sys.stdout.write(text)
    return 0


# --- demo --------------------------------------------------------------------------------

def cmd_demo(args: argparse.Namespace) -> int:
    from daemon.demo import run_demo

    return run_demo(keep=args.keep, speedup=args.speedup)

