"""The process's environment, set up in one place: what MLflow, ultralytics and OpenVINO read from `os.environ`.

- the tracking store (`tracking_uri`): $MLFLOW_TRACKING_URI, so that child processes (a sweep's workers) inherit
  the store this process writes to and the outage messages name it, and, for a tracking server over HTTP,
  MLflow's own retries off (its 7 retries with back-off sat more than 15 minutes on a stopped server;
  `tracking.client.retry` waits instead, for a bounded time, and says so).
- `offline`: ultralytics and OpenVINO kept off the network (core.offline), once per process, before the first
  `import ultralytics` or `import openvino`.
"""

from __future__ import annotations


def prepare_environment(tracking_uri: str | None = None, *, offline: bool = False) -> None:
    """Set the process's environment for the tracking store `tracking_uri` (when given) and for offline
    ultralytics/OpenVINO (when `offline`). Cheap when already done."""
    from garage_exp.core.state import STATE

    if tracking_uri:
        # The command's store: put back when the command ends (STATE.end), so the next command run in this
        # process (a test session, a benchmark) does not inherit it.
        if tracking_uri.startswith(("http://", "https://")):  # a user's own setting is kept
            STATE.setenv("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "0", "command", default=True)
            STATE.setenv("MLFLOW_HTTP_REQUEST_TIMEOUT", "30", "command", default=True)
        STATE.setenv("MLFLOW_TRACKING_URI", tracking_uri, "command")
    if offline:
        from garage_exp.core.offline import prepare_offline

        prepare_offline()
