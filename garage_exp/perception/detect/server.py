"""A detector behind a model server: `http://HOST:PORT/v2/models/NAME[/versions/V][?timeout=S&batch=N]` in
`detector.models` (timeout: seconds for connecting and for each answer, 30; batch: frames per request, 8, at
most the model's max_batch_size).

The server speaks the KServe v2 inference protocol (NVIDIA Triton's HTTP/REST API, also KServe's, Seldon's
MLServer's and OpenVINO Model Server's), through `tritonclient.http` with the binary tensor extension.
`grpc://` entries are refused: tritonclient's gRPC client needs a protobuf older than the one MLflow and Ray
bring here.

What the served model must look like (docs/perception.md, "A model server"):
- one input, UINT8 or FP32 (FP32: values 0-1), N x H x W x 3 (RGB) or N x 3 x H x W; a fixed H x W gets
  letterboxed frames, -1 gets the frames as they are;
- outputs in one of `tensors.LAYOUTS` (boxes/scores/classes, K x 6 rows, or ultralytics' raw head);
- class names: the model config's parameter `names` (a JSON list, a JSON mapping of index to name, or
  comma-separated), or the metadata's `parameters.names`, or, for a server that gives neither (a stock KServe
  server), the config's `detector.class_names.NAME`.

`check()` (preflight, before anything is written) asks for liveness, the model's readiness, metadata and config
and runs one probe frame: a server that is down, answers with an error or returns tensors of the wrong shape is
a GarageError naming the entry. During a run, a dropped connection is retried (RETRIES times, backing off); then,
or on an error answer, `detect` raises ServerError with the reason (the job ends FAILED with it).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any, Sequence
from urllib.parse import parse_qs, urlparse

import numpy as np

from garage_exp.core.errors import GarageError, JobFault
from garage_exp.perception.detect import tensors
from garage_exp.perception.detect.base import (WHERE, Detections, Entry, EntrySettings, checked,
                                               probe_frame)
from garage_exp.perception.detect.kinds import register_entry_kind
from garage_exp.scene.lenses import Lens

DATATYPES = {"UINT8": np.uint8, "FP32": np.float32}
RETRIES = 3  # a dropped connection is tried again this many times (0.5 s, 1 s, 2 s apart)


class ServerError(JobFault):
    """The server failed during a run (after the check passed): down for good, an error answer, bad tensors. An
    expected fault: the job ends FAILED with this one line, not a traceback."""

    def __init__(self, entry: str, reason: str):
        super().__init__(f"model server {entry}: {reason}")
        self.reason = reason


@dataclass
class Endpoint:
    """A parsed entry: where the server is, which model (and version; "" for the server's choice), how long to
    wait and how many frames a request carries."""

    entry: str
    address: str  # host:port
    ssl: bool
    model: str
    version: str = ""
    timeout: float = 30.0
    batch: int = 8


def parse(entry: str, where: str = WHERE) -> Endpoint:
    """`http(s)://HOST:PORT/v2/models/NAME[/versions/V][?timeout=S&batch=N]`; GarageError for anything else
    (grpc:// included)."""
    if entry.startswith("grpc://"):
        raise GarageError("grpc:// is not supported here (tritonclient's gRPC client needs protobuf < 7, older than "
                          "MLflow's); use the server's HTTP port, http://HOST:PORT/v2/models/NAME", where)
    url = urlparse(entry)
    parts = url.path.strip("/").split("/")
    try:
        port = url.port
    except ValueError:
        port = None
    ok = url.hostname and port and len(parts) in (3, 5) and parts[:2] == ["v2", "models"] and parts[2] and (
        len(parts) == 3 or (parts[3] == "versions" and parts[4]))
    if not ok:
        raise GarageError("a model server entry is http://HOST:PORT/v2/models/NAME[/versions/V]", where)
    query = parse_qs(url.query)
    unknown = sorted(set(query) - {"timeout", "batch"})
    if unknown:
        raise GarageError(f"unknown option(s) {unknown} (timeout=SECONDS, batch=FRAMES)", where)
    try:
        timeout = float(query.get("timeout", ["30"])[-1])
        batch = int(query.get("batch", ["8"])[-1])
    except ValueError:
        raise GarageError("timeout must be a number of seconds, batch a whole number of frames", where) from None
    if not (0 < timeout <= 3600 and 1 <= batch <= 1024):
        raise GarageError(f"timeout {timeout:g} s or batch {batch} out of range (0-3600 s, 1-1024 frames)", where)
    return Endpoint(entry, f"{url.hostname}:{port}", url.scheme == "https", parts[2],
                    parts[4] if len(parts) == 5 else "", timeout, batch)


# A model server (KServe v2 / Triton): one kind per scheme; grpc:// is refused in one line (`parse`).
@register_entry_kind("server grpc", prefix="grpc://")
@register_entry_kind("server https", prefix="https://")
@register_entry_kind("server http", prefix="http://")
class ServerEntry(Entry):
    """One model on a KServe v2 server (see the module's doc): `check()` before use; `detect(frames)` sends the
    frames in batches and returns one Detections per frame, in the frame's pixels, scores >= detector.conf."""

    kind = "server"

    def __init__(self, entry: str, settings: EntrySettings):
        super().__init__(entry, settings)
        self.endpoint = parse(self.entry, self.where)
        e = self.endpoint
        self.name = f"{e.model}_v{e.version}" if e.version else e.model
        self.device = f"server {e.address}"
        self.batch = e.batch
        self.names: list[str] = []  # the model's class names by index
        self.layout = ""
        self._input: dict = {}  # name, datatype, shape (with batch), nchw
        self._outputs: list[str] = []
        self._client: Any = None
        self._ready = False  # checked: the server answered the probe frame

    @property
    def conf(self) -> float:
        return self.settings.conf

    def device_note(self) -> str:
        return "the server picks its own device"

    # ----------------------------------------------------------------------------------------- the check
    def check(self, intrinsics: Lens | None = None) -> None:
        """Server live, model ready, metadata and config readable and of the contract's shape, one probe frame
        answered with tensors of the right shapes; GarageError naming the entry otherwise."""
        try:
            if not self._ready:
                self._check(intrinsics)
        except GarageError:
            raise
        except Exception as exc:  # noqa: BLE001 - the client raises many types; one line naming the entry
            raise GarageError(self._reason(exc), self.where) from None

    def _check(self, intrinsics: Lens | None) -> None:
        client = self._connect()
        e = self.endpoint
        if not client.is_server_live():
            raise GarageError("the server is up but not live", self.where)
        if not client.is_model_ready(e.model, e.version):
            raise GarageError(f"the server has no ready model {e.model!r}"
                              + (f" version {e.version}" if e.version else ""), self.where)
        meta = client.get_model_metadata(e.model, e.version)
        try:
            config = client.get_model_config(e.model, e.version)
        except Exception:  # noqa: BLE001 - the model config is Triton's extension; KServe servers may lack it
            config = {}
        self.names = self._class_names(class_names(config, meta))
        self.classes = tuple(self.names)
        self._input = input_of(meta, self.where)
        shapes = {o["name"]: [int(d) for d in o["shape"]] for o in meta.get("outputs", [])}
        try:
            self.layout = tensors.layout_of(shapes, len(self.names))
        except ValueError as exc:
            raise GarageError(str(exc), self.where) from None
        self._outputs = sorted(shapes)
        max_batch = int(config.get("max_batch_size", 0) or 0)
        if max_batch > 0:
            self.batch = min(self.batch, max_batch)
        if self._input["shape"][0] not in (-1,):  # a fixed batch dimension: send exactly that many
            self.batch = int(self._input["shape"][0])
        try:
            self._infer([probe_frame(intrinsics)])
        except ServerError as exc:
            raise GarageError(f"the probe frame failed: {exc.reason}", self.where) from None
        self._ready = True

    def _class_names(self, served: list[str]) -> list[str]:
        """The model's class names: the server's, or those the config gives (detector.class_names.NAME: a stock
        KServe server has no config route and drops the metadata's `parameters`); both must agree."""
        given = list(self.given_classes)
        if served and given and served != given:
            raise GarageError(f"the server's class names ({', '.join(served[:4])}, ...) differ from "
                              f"detector.class_names.{self.name} ({', '.join(given[:4])}, ...): give one of them",
                              self.where)
        if not (served or given):
            raise GarageError(f"the model gives no class names (no config parameter or metadata `parameters` "
                              f"`names`, as on a stock KServe server): give them, +detector.class_names.{self.name}="
                              "[person,bicycle,car,...] or a file of them (docs/perception.md)", self.where)
        return served or given

    def _connect(self):
        if self._client is None:
            import tritonclient.http as httpclient

            self._client = httpclient.InferenceServerClient(
                self.endpoint.address, ssl=self.endpoint.ssl, connection_timeout=self.endpoint.timeout,
                network_timeout=self.endpoint.timeout)
        return self._client

    def _reconnect(self) -> None:
        client, self._client = self._client, None
        try:
            if client is not None:
                client.close()
        except Exception:  # noqa: BLE001 - a broken client is dropped either way
            pass
        self._connect()

    @staticmethod
    def _reason(exc: BaseException) -> str:
        text = (getattr(exc, "message", None) and exc.message()) if callable(getattr(exc, "message", None)) else None
        text = text or str(exc) or type(exc).__name__
        if isinstance(exc, (ConnectionError, OSError)) or "connect" in text.lower():
            return f"the server is not reachable ({type(exc).__name__}: {text})".splitlines()[0]
        return text.splitlines()[0]

    # ------------------------------------------------------------------------------------------ detection
    def detect(self, frames: Sequence[np.ndarray], intrinsics: Sequence[Lens | None] = ()
               ) -> list[Detections]:
        """One Detections per frame (boxes in the frame's pixels); ServerError when the server fails."""
        self.check()
        out = []
        for start in range(0, len(frames), self.batch):
            out += self._infer(list(frames[start:start + self.batch]))
        return out

    def _infer(self, frames: list[np.ndarray]) -> list[Detections]:
        batch, boxes_of = self._pack(frames)
        outputs = self._send(batch)
        try:
            decoded = tensors.decode(self.layout, outputs, self.conf, len(self.names))
            if len(decoded) < len(frames):
                raise ValueError(f"{len(decoded)} answers for {len(frames)} frames")
        except (ValueError, IndexError) as exc:
            raise ServerError(self.entry, f"wrong tensors: {exc}") from None
        result = []
        for frame, box_map, (boxes, scores, cls) in zip(frames, boxes_of, decoded):
            if len(cls) and (cls.min() < 0 or cls.max() >= len(self.names)):
                raise ServerError(self.entry, f"class index {int(cls.max())} outside the model's "
                                  f"{len(self.names)} class names")
            h, w = frame.shape[:2]
            dets = Detections(box_map.unmap(boxes, w, h), scores.astype(np.float32), [self.names[int(k)] for k in cls])
            try:  # the interface's contract: scores in [0, 1], boxes x1 <= x2 in the frame's pixels
                result.append(checked(dets, frame, "the answer"))
            except ValueError as exc:
                raise ServerError(self.entry, f"wrong tensors: {exc}") from None
        return result

    def _pack(self, frames: list[np.ndarray]) -> tuple[np.ndarray, list[tensors.Letterbox]]:
        """The batch tensor in the model's layout and type, padded to a fixed batch size with blank frames."""
        _, *dims = self._input["shape"]
        nchw = self._input["nchw"]
        height, width = (dims[1], dims[2]) if nchw else (dims[0], dims[1])
        fitted, maps = [], []
        for frame in frames:
            if height > 0 and width > 0:
                frame, box_map = tensors.letterbox(frame, height, width)
            else:
                box_map = tensors.Letterbox()
            fitted.append(frame)
            maps.append(box_map)
        while len(fitted) < self.batch and self._input["shape"][0] > 0:
            fitted.append(np.zeros_like(fitted[0]))
        batch = np.stack(fitted)
        if nchw:
            batch = batch.transpose(0, 3, 1, 2)
        if self._input["datatype"] == "FP32":
            batch = batch.astype(np.float32) / 255.0
        return np.ascontiguousarray(batch), maps

    def _send(self, batch: np.ndarray) -> dict[str, np.ndarray]:
        """One inference request; a dropped connection is retried RETRIES times on a fresh connection."""
        import tritonclient.http as httpclient
        from tritonclient.utils import InferenceServerException

        inp = httpclient.InferInput(self._input["name"], list(batch.shape), self._input["datatype"])
        inp.set_data_from_numpy(batch, binary_data=True)
        wanted = [httpclient.InferRequestedOutput(n, binary_data=True) for n in self._outputs]
        e = self.endpoint
        for attempt in range(RETRIES + 1):
            try:
                result = self._connect().infer(e.model, [inp], model_version=e.version, outputs=wanted)
                answer = {n: result.as_numpy(n) for n in self._outputs}
                missing = [n for n, a in answer.items() if a is None]
                if missing:
                    raise ServerError(self.entry, f"the answer lacks output(s) {missing}")
                return answer
            except InferenceServerException as exc:
                reason = self._reason(exc)
                if not _dropped(reason):
                    raise ServerError(self.entry, f"the server answered with an error: {reason}") from None
                error = reason
            except (ConnectionError, OSError, EOFError) as exc:
                error = self._reason(exc)
            except Exception as exc:  # noqa: BLE001 - geventhttpclient's parser errors on a half-sent answer
                if isinstance(exc, ServerError):
                    raise
                error = f"{type(exc).__name__}: {exc}"
            if attempt < RETRIES:
                time.sleep(0.5 * 2 ** attempt)
                self._reconnect()
        raise ServerError(self.entry, f"the connection failed {RETRIES + 1} times: {error}".splitlines()[0])


def _dropped(reason: str) -> bool:
    """Whether an InferenceServerException is a lost connection (worth retrying) rather than an answer."""
    low = reason.lower()
    return any(w in low for w in ("connection", "broken pipe", "reset by peer", "timed out", "timeout", "eof"))


def class_names(config: dict, meta: dict) -> list[str]:
    """The class names from the config's (Triton: {"names": {"string_value": ...}}) or the metadata's
    `parameters`: a JSON list, a JSON mapping of index to name, or comma-separated names."""
    for params in (config.get("parameters") or {}, meta.get("parameters") or {}):
        raw = params.get("names")
        if isinstance(raw, dict):
            raw = raw.get("string_value", raw.get("stringParam"))
        if raw is None:
            continue
        if isinstance(raw, str):
            try:
                raw = json.loads(raw)
            except ValueError:
                raw = [n.strip() for n in raw.split(",")]
        if isinstance(raw, dict):
            return [str(raw[k]) for k in sorted(raw, key=int)]
        return [str(n) for n in raw]
    return []


def input_of(meta: dict, where: str) -> dict:
    """The one image input: name, datatype (UINT8 | FP32), shape with the batch dimension, NCHW or NHWC."""
    inputs = meta.get("inputs") or []
    if len(inputs) != 1:
        raise GarageError(f"the model must take one image input, it takes {len(inputs)}", where)
    inp = inputs[0]
    shape = [int(d) for d in inp["shape"]]
    if inp["datatype"] not in DATATYPES:
        raise GarageError(f"input {inp['name']!r} is {inp['datatype']}; use UINT8 or FP32", where)
    if len(shape) == 4 and shape[3] == 3:
        nchw = False
    elif len(shape) == 4 and shape[1] == 3:
        nchw = True
    else:
        raise GarageError(f"input {inp['name']!r} has shape {shape}; use N x H x W x 3 or N x 3 x H x W", where)
    return {"name": inp["name"], "datatype": inp["datatype"], "shape": shape, "nchw": nchw}
