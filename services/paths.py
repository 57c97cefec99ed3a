"""Where a sweep's things go: the project and run directories, and sweep paths made absolute; tracking URIs
checked (a scheme MLflow opens, a server that answers) and redacted for messages.

Everything here is resolved in the driver before anything is shipped to a Ray worker (a worker's
working directory is a temporary copy that Ray deletes), so nothing lands in Ray's temporary dirs.
"""

from __future__ import annotations

import os
import re
from pathlib import Path


def project_dir() -> Path:
    """Where relative paths of a sweep are anchored: $FLASHNAV_PROJECT_DIR, else the working directory."""
    return Path(os.environ.get("FLASHNAV_PROJECT_DIR") or os.getcwd()).resolve()


def in_ray_job() -> bool:
    """True in the driver of a ``ray job submit`` entrypoint (its cwd is a temporary copy)."""
    return "RAY_JOB_CONFIG_JSON_ENV_VAR" in os.environ


def runs_dir() -> Path:
    """The project's run directory (absolute): $FLASHNAV_RUNS_DIR, else <project>/runs.

    In a Ray job with neither variable set, the cwd is a temporary unpacked working dir that Ray deletes;
    fall back to ~/flashnav-runs on the head node (``flashnav services up`` sets FLASHNAV_RUNS_DIR).
    """
    if os.environ.get("FLASHNAV_RUNS_DIR"):
        return Path(os.environ["FLASHNAV_RUNS_DIR"]).expanduser().resolve()
    if in_ray_job() and not os.environ.get("FLASHNAV_PROJECT_DIR"):
        return (Path.home() / "flashnav-runs").resolve()
    return project_dir() / "runs"


def _absolute(path: str) -> str:
    p = Path(path).expanduser()
    return str(p if p.is_absolute() else (project_dir() / p).resolve())


def resolve_db_url(url: str | None, default_file: str) -> str:
    """An SQLAlchemy/MLflow URL with any relative sqlite path made absolute; None -> <runs>/<default_file>."""
    if url is None:
        return f"sqlite:///{runs_dir() / default_file}"
    if url.startswith("sqlite:///"):
        rest = url[len("sqlite:///") :]
        return url if rest.startswith("/") or rest == ":memory:" else f"sqlite:///{_absolute(rest)}"
    return url  # http(s)://, postgresql://, databricks...: location independent already


def resolve_tracking_uri(explicit: str | None) -> str:
    """The sweep's tracking.tracking_uri, else $MLFLOW_TRACKING_URI, else sqlite:///<runs>/mlflow.db.

    A file store (a folder, or file://) is refused with ValueError unless $MLFLOW_ALLOW_FILE_STORE is true:
    MLflow refuses it then too, but only once Ray is up; where allowed, a relative folder is made absolute."""
    uri = explicit or os.environ.get("MLFLOW_TRACKING_URI") or None
    if uri is not None and ("://" not in uri or uri.startswith("file:")):
        if os.environ.get("MLFLOW_ALLOW_FILE_STORE", "").lower() not in ("1", "true", "yes"):
            where = "tracking.tracking_uri" if explicit else "$MLFLOW_TRACKING_URI"
            raise ValueError(f"{where} {uri!r} is an MLflow file store, which MLflow keeps in maintenance mode and "
                             "refuses to write to: use sqlite:///PATH/mlflow.db (the default: "
                             f"sqlite:///{runs_dir() / 'mlflow.db'}) or an http(s):// tracking server, or set "
                             "MLFLOW_ALLOW_FILE_STORE=true")
        if "://" not in uri:
            return f"file://{_absolute(uri)}"
        return uri
    return resolve_db_url(uri, "mlflow.db")


def resolve_storage(path: str | None) -> str:
    """Ray storage path: URIs (s3://, gs://, ...) as given, local paths absolute; None -> <runs>/ray."""
    if path is None:
        return str(runs_dir() / "ray")
    if "://" in path:
        return path
    return _absolute(path)


#: tracking-URI schemes an MlflowClient opens (a SQLAlchemy dialect suffix, postgresql+psycopg2, is allowed)
URI_SCHEMES = ("", "file", "sqlite", "http", "https", "postgresql", "mysql", "mssql", "databricks")
#: seconds an MLflow server gets to answer its health check; MLflow itself retries a dead server
#: for minutes (7 retries with backoff, 120 s per request), which looks like a hang
PROBE_TIMEOUT_S = 5.0


def redact_uri(uri: str) -> str:
    return re.sub(r"//[^/@]+@", "//***@", uri)   # never print credentials embedded in a server URI


#: the first 16 bytes of every SQLite database file
SQLITE_MAGIC = b"SQLite format 3\x00"


def check_sqlite_url(url: str, what: str, *, read_only: bool = False) -> None:
    """ValueError naming ``what`` (the key or flag) for a ``sqlite:///`` URL whose file cannot be an SQLite
    database: a folder, a file of another kind (the sweep's own YAML, say), a path under a file; with
    ``read_only`` also an empty file, which MLflow would fill with its tables. Other URLs pass."""
    if not url.startswith("sqlite:///") or ":memory:" in url:
        return
    path = Path(url[len("sqlite:///"):].split("?")[0])
    if path.is_dir():
        raise ValueError(f"{what} {url}: {path} is a folder, not an SQLite database file")
    if path.exists():
        with open(path, "rb") as f:
            head = f.read(len(SQLITE_MAGIC))
        if head != SQLITE_MAGIC and (head or read_only):
            raise ValueError(f"{what} {url}: {path} is {'an empty file' if not head else 'not an SQLite database'}")
        return
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{what} {url}: {parent} is a file, so {path} cannot be made")


def check_tracking_uri(uri: str, timeout: float = PROBE_TIMEOUT_S, *, read_only: bool = False,
                       what: str = "tracking URI") -> None:
    """ValueError naming the (redacted) URI for a scheme MLflow cannot open, an SQLite file that cannot be an
    MLflow store (:func:`check_sqlite_url`), or an http(s) server that does not answer its health check within
    ``timeout`` seconds."""
    import urllib.error
    import urllib.parse
    import urllib.request

    parsed = urllib.parse.urlparse(uri)
    scheme = parsed.scheme.split("+")[0].lower()
    if len(scheme) == 1:  # a Windows drive letter (C:\runs), a plain path to MLflow
        scheme = ""
    if scheme not in URI_SCHEMES:
        raise ValueError(f"{what} {redact_uri(uri)}: unsupported scheme {parsed.scheme!r} (use sqlite:///FILE, "
                         "http(s)://HOST:PORT, file:///DIR, postgresql://..., mysql://...)")
    if scheme == "sqlite":
        check_sqlite_url(uri, what, read_only=read_only)
    if scheme not in ("http", "https"):
        return
    # credentials stay out of the probe URL (urllib cannot parse user:password@host anyway)
    probe = parsed._replace(netloc=parsed.netloc.rpartition("@")[2], path=parsed.path.rstrip("/") + "/health",
                            query="", fragment="").geturl()
    try:
        with urllib.request.urlopen(probe, timeout=timeout):
            pass
    except urllib.error.HTTPError:
        pass  # something answered (an auth proxy, an older server): MLflow reports what follows
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", None) or exc
        raise ValueError(f"{what}: no MLflow server answers at {redact_uri(uri)} within {timeout:g} s ({reason}); "
                         "start one (flashnav services up) or fix the URI") from None
