"""The local experiment stack: a Ray head (dashboard + jobs API) and an MLflow server, on 127.0.0.1 only.

    flashnav services up [--no-mlflow] [--auth token|disabled] [--dashboard-port 8265] [--mlflow-port 5000]
    flashnav services status
    flashnav services down

``up`` starts ``ray start --head --block`` (so the head's processes stay children of one process that
``down`` can stop) and ``mlflow server --backend-store-uri sqlite:///<runs>/mlflow.db``, each in its own
session, with logs, pid files and a state file under ``<runs>/services/``; it waits until both answer
over HTTP. ``down`` stops only the process trees that ``up`` recorded (never ``ray stop``, which would
kill every Ray process of every user on the machine).

Token auth (Ray >= 2.59): the head is started with an explicit RAY_AUTH_MODE, ``token`` by default (the token
is ~/.ray/auth_token, made by ``ray get-auth-token --generate`` when missing), because Ray's dashboard agent
serves a jobs API of its own on the node's network address whatever the flags: without auth anyone who reaches
the machine could run commands on it (a probe did, 2026-12-03). Clients then need ``export RAY_AUTH_MODE=token``
(``up`` and ``status`` print the line; ``flashnav sweep submit`` reads the mode from the state file).
``--auth disabled`` is for a machine no one else can reach.

The head's environment carries FLASHNAV_RUNS_DIR, FLASHNAV_PROJECT_DIR and MLFLOW_TRACKING_URI (the
server) down to job drivers, so ``ray job submit --working-dir . -- flashnav sweep run ...`` writes to
this project's runs/ and to the server, not into the job's temporary working dir.

Binding: the HTTP endpoints people use (dashboard + jobs API, MLflow) listen on 127.0.0.1 only. Ray's
internal servers (GCS, raylet, the client server and the dashboard agent, whose HTTP jobs API accepts jobs)
cannot be confined to loopback: Ray maps 127.0.0.1 to the node's address and binds them on all interfaces
(``--node-ip-address 127.0.0.1`` too, Ray 2.60). Hence token auth by default; with ``--auth disabled`` keep
them behind a firewall.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

from services.paths import project_dir, runs_dir

HOST = "127.0.0.1"


def services_dir() -> Path:
    return runs_dir() / "services"


def _state_path() -> Path:
    return services_dir() / "state.json"


def load_state() -> dict[str, Any]:
    path = _state_path()
    return json.loads(path.read_text()) if path.exists() else {}


def _save_state(state: dict[str, Any]) -> None:
    services_dir().mkdir(parents=True, exist_ok=True)
    _state_path().write_text(json.dumps(state, indent=1))


def jobs_address() -> str:
    """The jobs API of the local stack (its recorded dashboard port), else the default one."""
    ray = load_state().get("ray") or {}
    return ray.get("jobs_address", f"http://{HOST}:8265")


def align_client_auth() -> None:
    """Make this process's Ray client use the auth mode the local head was started with (unless set)."""
    mode = (load_state().get("ray") or {}).get("auth_mode")
    if mode and "RAY_AUTH_MODE" not in os.environ:
        os.environ["RAY_AUTH_MODE"] = mode


# ---------------------------------------------------------------- processes (Linux /proc; no psutil)


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as servers do: TIME_WAIT is no conflict
        try:
            s.bind((HOST, port))
            return True
        except OSError:
            return False


def _stat(pid: int) -> list[str] | None:
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text[text.rindex(")") + 2 :].split()  # fields after "pid (comm) "


def start_time(pid: int) -> int | None:
    """The kernel's start time of ``pid`` (guards against a recycled pid)."""
    fields = _stat(pid)
    return int(fields[19]) if fields else None


def alive(pid: int | None, started: int | None = None) -> bool:
    if not pid:
        return False
    fields = _stat(pid)
    if fields is None or fields[0] == "Z":
        return False
    return started is None or int(fields[19]) == started


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (children first listed before theirs)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = _stat(int(entry.name))
            if fields:
                children.setdefault(int(fields[1]), []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def stop_tree(pid: int, started: int | None, timeout: float = 5.0) -> bool:
    """SIGTERM ``pid`` and its descendants (collected first), SIGKILL what is left after ``timeout``."""
    if not alive(pid, started):
        return False
    tree = [pid, *descendants(pid)]
    _signal(tree, signal.SIGTERM)  # the root first: `ray start --block` shuts its processes down on SIGTERM
    if not _gone(tree, timeout):
        _signal([p for p in tree if alive(p)], signal.SIGKILL)
        _gone(tree, 10.0)  # SIGKILL is asynchronous: a many-threaded process takes a moment to exit
    return True


def _signal(pids: list[int], sig: int) -> None:
    for target in pids:
        try:
            os.kill(target, sig)
        except ProcessLookupError:
            pass


def _gone(pids: list[int], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while True:
        _reap(pids)
        if not any(alive(p) for p in pids):
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.1)


def _reap(pids: list[int]) -> None:
    for p in pids:  # our own children become zombies until waited for
        try:
            os.waitpid(p, os.WNOHANG)
        except ChildProcessError:
            pass


def http_ok(url: str, timeout: float = 5.0) -> bool:
    """The server answers: a 2xx, or 401 (a head in token-auth mode answers unauthenticated probes so).
    ``timeout``: seconds for one answer (a server on a loaded 2-core machine took over 2 s: CI, 2026-11-27)."""
    try:
        with urllib.request.urlopen(url, timeout=timeout) as response:
            return 200 <= response.status < 300
    except urllib.error.HTTPError as exc:
        return exc.code == 401
    except OSError:
        return False


def _wait_healthy(name: str, url: str, pid: int, log: Path, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if http_ok(url):
            return
        if not alive(pid):
            raise RuntimeError(f"{name} exited during start; last log lines ({log}):\n{_tail(log)}")
        time.sleep(0.5)
    raise RuntimeError(f"{name} did not answer {url} within {timeout:.0f} s; log: {log}\n{_tail(log)}")


def _tail(path: Path, lines: int = 20) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


def _tool(name: str) -> str:
    """The console script next to this interpreter (the venv's), else whatever PATH finds."""
    local = Path(sys.executable).parent / name
    return str(local) if local.exists() else name


def _spawn(name: str, command: list[str], env: dict[str, str]) -> tuple[int, Path]:
    log = services_dir() / f"{name}.log"
    with open(log, "ab") as out:
        out.write(f"\n--- {time.strftime('%Y-%m-%d %H:%M:%S')} {' '.join(command)}\n".encode())
        out.flush()
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                   env=env, cwd=str(project_dir()), start_new_session=True)
    (services_dir() / f"{name}.pid").write_text(f"{process.pid}\n")
    return process.pid, log


# ---------------------------------------------------------------- up / down / status


def ensure_token() -> None:
    """~/.ray/auth_token (or $RAY_AUTH_TOKEN_PATH / $RAY_AUTH_TOKEN), made when missing: ``ray start`` in token
    mode refuses to start without one."""
    done = subprocess.run([_tool("ray"), "get-auth-token", "--generate"], env={**os.environ, "RAY_AUTH_MODE": "token"},
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # (it prints the token)
    if done.returncode:
        raise RuntimeError(f"could not make Ray's auth token (ray get-auth-token --generate: "
                           f"{done.stderr.strip()[-300:]}); or start with --auth disabled on a machine no one "
                           "else can reach")


def up(*, mlflow: bool = True, auth: str = "token", ray_port: int = 6379, dashboard_port: int = 8265,
       mlflow_port: int = 5000, ray_temp_dir: str | None = None, num_cpus: int | None = None,
       timeout: float = 120.0, echo=print) -> dict[str, Any]:
    """Start what is not running yet; returns the state (addresses, pids)."""
    services_dir().mkdir(parents=True, exist_ok=True)
    state = load_state()
    runs = runs_dir()
    tracking = f"http://{HOST}:{mlflow_port}"
    if mlflow and not alive(*_pid(state, "mlflow")):
        for port in (mlflow_port,):
            if not _port_free(port):
                raise RuntimeError(f"port {port} on {HOST} is taken: pass --mlflow-port")
        command = [_tool("mlflow"), "server", "--host", HOST, "--port", str(mlflow_port),
                   "--backend-store-uri", f"sqlite:///{runs / 'mlflow.db'}",
                   "--artifacts-destination", str(runs / "mlartifacts"), "--workers", "1"]
        pid, log = _spawn("mlflow", command, dict(os.environ))
        state["mlflow"] = {"pid": pid, "start_time": start_time(pid), "tracking_uri": tracking,
                           "health": f"{tracking}/health", "log": str(log)}
        _save_state(state)
        _wait_healthy("mlflow server", f"{tracking}/health", pid, log, timeout)
        echo(f"mlflow server up: {tracking} (pid {pid}, store {runs / 'mlflow.db'})")
    if not alive(*_pid(state, "ray")):
        for port in (ray_port, dashboard_port):
            if not _port_free(port):
                raise RuntimeError(f"port {port} on {HOST} is taken: pass --ray-port / --dashboard-port")
        # This interpreter's bin dir first: job entrypoints (`flashnav`, `python`) resolve to this venv.
        path = os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])
        if auth == "token":
            ensure_token()
        env = {**os.environ, "PATH": path, "RAY_AUTH_MODE": auth, "FLASHNAV_RUNS_DIR": str(runs),
               "FLASHNAV_PROJECT_DIR": str(project_dir()), "RAY_USAGE_STATS_ENABLED": "0"}
        if mlflow:
            env["MLFLOW_TRACKING_URI"] = tracking
        # Auxiliary ports on free numbers so that this head can coexist with other Ray instances.
        command = [_tool("ray"), "start", "--head", "--block", "--port", str(ray_port),
                   "--include-dashboard", "true", "--dashboard-host", HOST, "--dashboard-port", str(dashboard_port),
                   "--ray-client-server-port", str(free_port()), "--dashboard-agent-listen-port", str(free_port()),
                   "--disable-usage-stats"]
        if ray_temp_dir:
            command += ["--temp-dir", str(Path(ray_temp_dir).resolve())]
        if num_cpus is not None:
            command += ["--num-cpus", str(num_cpus)]
        pid, log = _spawn("ray", command, env)
        jobs = f"http://{HOST}:{dashboard_port}"
        state["ray"] = {"pid": pid, "start_time": start_time(pid), "address": f"{HOST}:{ray_port}",
                        "jobs_address": jobs, "health": f"{jobs}/api/version", "auth_mode": auth, "log": str(log)}
        _save_state(state)
        _wait_healthy("ray head", f"{jobs}/api/version", pid, log, timeout)
        echo(f"ray head up: jobs API {jobs}, cluster {HOST}:{ray_port} (pid {pid}, RAY_AUTH_MODE={auth})")
        if auth == "disabled":
            echo("warning: token auth is off and Ray's internal ports (GCS, raylet, the dashboard agent's jobs API) "
                 "listen on every interface: anyone who reaches this machine can run jobs on it; firewall them or "
                 "leave --auth at token")
    return state


def _pid(state: dict, name: str) -> tuple[int | None, int | None]:
    entry = state.get(name) or {}
    return entry.get("pid"), entry.get("start_time")


def down(echo=print) -> int:
    """Stop the services ``up`` recorded; returns how many were running."""
    state = load_state()
    stopped = 0
    for name in ("ray", "mlflow"):  # Ray first: its job drivers may still be writing to the server
        pid, started = _pid(state, name)
        if pid and stop_tree(pid, started):
            stopped += 1
            echo(f"stopped {name} (pid {pid})")
        (services_dir() / f"{name}.pid").unlink(missing_ok=True)
        state.pop(name, None)
    _save_state(state)
    if not stopped:
        echo("nothing was running")
    return stopped


def status(echo=print) -> int:
    """Print each service's state; 0 when every recorded service is alive and healthy, else 3."""
    state = load_state()
    healthy = bool(state.get("ray") or state.get("mlflow"))
    for name in ("ray", "mlflow"):
        entry = state.get(name)
        if not entry:
            echo(f"{name}: not started")
            continue
        up_ = alive(entry["pid"], entry.get("start_time"))
        ok = up_ and http_ok(entry["health"])
        healthy &= ok
        where = entry.get("jobs_address") or entry.get("tracking_uri")
        echo(f"{name}: {'up' if ok else 'running, not answering' if up_ else 'down'} {where} (pid {entry['pid']})")
    if state.get("mlflow"):
        echo(f"  export MLFLOW_TRACKING_URI={state['mlflow']['tracking_uri']}")
    if state.get("ray"):
        if state["ray"].get("auth_mode") == "token":
            echo("  export RAY_AUTH_MODE=token")
        echo(f"  ray job submit --address {state['ray']['jobs_address']} --working-dir . -- "
             "flashnav sweep run sweeps/quickstart.yaml")
    return 0 if healthy else 3


# ---------------------------------------------------------------- CLI


def _cmd(args: argparse.Namespace) -> int:
    try:
        if args.services_command == "up":
            up(mlflow=not args.no_mlflow, auth=args.auth, ray_port=args.ray_port, dashboard_port=args.dashboard_port,
               mlflow_port=args.mlflow_port, ray_temp_dir=args.ray_temp_dir, num_cpus=args.num_cpus)
            return status()
        if args.services_command == "down":
            down()
            return 0
        return status()
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


def _add_commands(sub) -> None:
    start = sub.add_parser("up", help="start a local Ray head and MLflow server on 127.0.0.1")
    start.add_argument("--no-mlflow", action="store_true", help="Ray head only")
    start.add_argument("--auth", choices=("token", "disabled"), default=os.environ.get("RAY_AUTH_MODE", "token"),
                       help="Ray token auth of the head (default $RAY_AUTH_MODE, else token: Ray's dashboard agent "
                            "accepts jobs on every interface; disabled only where no one else can reach the machine)")
    start.add_argument("--ray-port", type=int, default=6379)
    start.add_argument("--dashboard-port", type=int, default=8265, help="dashboard + jobs API")
    start.add_argument("--mlflow-port", type=int, default=5000)
    start.add_argument("--ray-temp-dir", help="Ray's temp/session dir (default Ray's /tmp/ray)")
    start.add_argument("--num-cpus", type=int, help="CPUs the head offers (default: all)")
    sub.add_parser("down", help="stop what `up` started (and nothing else)")
    sub.add_parser("status", help="which services are up; exit 3 when one is not")
    for parser in sub.choices.values():
        parser.set_defaults(func=_cmd)


def register_cli(subparsers) -> None:
    """Entry point ``flashnav.commands: services``: adds ``flashnav services up|down|status``."""
    parser = subparsers.add_parser("services", help="local Ray head + MLflow server (up / down / status)")
    _add_commands(parser.add_subparsers(dest="services_command", metavar="{up,down,status}", required=True))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m services.stack", description=__doc__.split("\n\n")[0])
    _add_commands(parser.add_subparsers(dest="services_command", metavar="{up,down,status}", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
