"""Lines for the log file only: what a model loader says while it loads ("Loading ... for OpenVINO inference",
"loaded openvino model ... in 1.2 s") belongs in a job's app.log, not on the terminal, where it would bury the
line that matters (a refusal, the sweep's progress).

`FILE_LOG` ("garage_exp.loading") does not propagate; its handler hands each record to the file handlers of the
root logger as they are when the record is made (Hydra replaces them at each job's start). Where none exists
(a sweep's checks before its first job), the line is dropped. (perception/detect/ultralytics_entry.py sends
ultralytics' own info lines here while it loads a model.)
"""

from __future__ import annotations

import logging

FILE_LOG = logging.getLogger("garage_exp.loading")


class _ToLogFiles(logging.Handler):
    def emit(self, record: logging.LogRecord) -> None:
        for handler in logging.getLogger().handlers:
            if isinstance(handler, logging.FileHandler) and record.levelno >= handler.level:
                handler.handle(record)


if not FILE_LOG.handlers:
    FILE_LOG.addHandler(_ToLogFiles())
    FILE_LOG.propagate = False
    FILE_LOG.setLevel(logging.INFO)
