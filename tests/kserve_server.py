"""A small KServe v2 / Triton HTTP inference server for the tests: real models behind the real protocol.

    python tests/kserve_server.py PORT NAME=MODEL [NAME=MODEL ...] [--fault KIND]

MODEL is an ONNX file (run by onnxruntime; class names from its metadata `names`, a JSON list) or an OpenVINO
export folder (*_openvino_model; class names from its metadata.yaml; batch 1, so a batch is run frame by frame).
Endpoints: /v2/health/live|ready, /v2/models/NAME[/versions/V] (metadata), .../ready, .../config (Triton's, with
the `names` parameter and max_batch_size 8), .../infer (JSON or the binary tensor extension, as tritonclient
sends it). Faults, for the tests of what a client does with a bad server:
  error        every inference answers HTTP 500 with an error message
  shapes       every output loses its last dimension's last element (boxes N x K x 3, ...)
  drop=N       the first N inference requests have their connection closed without an answer
  die-after=N  the process SIGKILLs itself on inference request N + 1 (a crash mid-run)
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np

TYPES = {"UINT8": np.uint8, "FP32": np.float32, "INT64": np.int64, "FP64": np.float64, "INT32": np.int32}
NAMES = {v: k for k, v in TYPES.items()}
ORT_TYPES = {"tensor(uint8)": "UINT8", "tensor(float)": "FP32", "tensor(int64)": "INT64"}


class OnnxModel:
    def __init__(self, path: Path):
        import onnxruntime as ort

        self.session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        self.names = json.loads(self.session.get_modelmeta().custom_metadata_map["names"])
        self.inputs = [{"name": i.name, "datatype": ORT_TYPES[i.type], "shape": _dims(i.shape)}
                       for i in self.session.get_inputs()]
        self.outputs = [{"name": o.name, "datatype": ORT_TYPES[o.type], "shape": _dims(o.shape)}
                        for o in self.session.get_outputs()]

    def run(self, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        names = [o["name"] for o in self.outputs]
        return dict(zip(names, self.session.run(names, feeds)))


class OpenVinoModel:
    """An ultralytics OpenVINO export: FP32 1 x 3 x H x W in, 1 x (4 + C) x A (or 1 x K x 6) out."""

    def __init__(self, folder: Path):
        import openvino as ov
        import yaml

        core = ov.Core()
        self.compiled = core.compile_model(core.read_model(next(folder.glob("*.xml"))), "CPU",
                                           {"INFERENCE_NUM_THREADS": 1})
        names = yaml.safe_load((folder / "metadata.yaml").read_text())["names"]
        self.names = [names[k] for k in sorted(names)]
        port_in, port_out = self.compiled.inputs[0], self.compiled.outputs[0]
        self.inputs = [{"name": "images", "datatype": "FP32", "shape": [-1, *list(port_in.shape)[1:]]}]
        self.outputs = [{"name": "output0", "datatype": "FP32", "shape": [-1, *list(port_out.shape)[1:]]}]

    def run(self, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        (batch,) = feeds.values()
        return {"output0": np.concatenate([self.compiled(frame[None])[0] for frame in batch])}


def _dims(shape) -> list[int]:
    return [d if isinstance(d, int) else -1 for d in shape]


class Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"  # keep-alive, as tritonclient's connection pool expects
    models: dict = {}
    fault = ""
    count = 0
    lock = threading.Lock()

    def log_message(self, *args):  # quiet
        pass

    def _send(self, code: int, body: bytes = b"", headers: dict | None = None) -> None:
        self.send_response(code)
        for k, v in (headers or {"Content-Type": "application/json"}).items():
            self.send_header(k, v)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def _json(self, code: int, obj) -> None:
        self._send(code, json.dumps(obj).encode())

    def _model(self, parts: list[str]):
        """(model, the rest of the path) for /v2/models/NAME[/versions/V]/..., or None after a 404."""
        model = self.models.get(parts[2]) if len(parts) > 2 else None
        if model is None:
            self._json(404, {"error": f"unknown model {parts[2] if len(parts) > 2 else ''!r}"})
            return None, []
        rest = parts[3:]
        if rest[:1] == ["versions"]:
            if rest[1:2] != ["1"]:
                self._json(404, {"error": f"model {parts[2]!r} has no version {rest[1:2]}"})
                return None, []
            rest = rest[2:]
        return model, rest

    def do_GET(self):
        parts = self.path.split("?")[0].strip("/").split("/")
        if parts[:2] == ["v2", "health"]:
            return self._send(200)
        if parts == ["v2"]:
            return self._json(200, {"name": "garage-test-server", "version": "1", "extensions": ["binary_tensor_data"]})
        if parts[:2] != ["v2", "models"]:
            return self._json(404, {"error": "not found"})
        model, rest = self._model(parts)
        if model is None:
            return None
        if rest == []:
            return self._json(200, {"name": parts[2], "versions": ["1"], "platform": "test",
                                    "inputs": model.inputs, "outputs": model.outputs})
        if rest == ["ready"]:
            return self._send(200)
        if rest == ["config"]:
            return self._json(200, {"name": parts[2], "max_batch_size": 8,
                                    "parameters": {"names": {"string_value": json.dumps(model.names)}}})
        return self._json(404, {"error": "not found"})

    def do_POST(self):
        parts = self.path.split("?")[0].strip("/").split("/")
        model, rest = self._model(parts) if parts[:2] == ["v2", "models"] else (None, [])
        if model is None or rest != ["infer"]:
            return None if model is None else self._json(404, {"error": "not found"})
        with self.lock:
            Handler.count += 1
            count = Handler.count
        body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
        if self.fault.startswith("die-after=") and count > int(self.fault.split("=")[1]):
            os.kill(os.getpid(), signal.SIGKILL)
        if self.fault.startswith("drop=") and count <= int(self.fault.split("=")[1]):
            self.close_connection = True
            self.connection.shutdown(2)
            return None
        if self.fault == "error":
            return self._json(500, {"error": "model crashed: CUDA out of memory (a fault injected by the test)"})
        try:
            feeds, wanted = parse_request(body, self.headers)
            outputs = model.run({model.inputs[0]["name"]: next(iter(feeds.values()))})
        except Exception as exc:  # noqa: BLE001 - the answer says what went wrong, as a real server's does
            return self._json(400, {"error": f"{type(exc).__name__}: {exc}"})
        print(f"infer {parts[2]} batch={len(next(iter(feeds.values())))}", flush=True)  # the tests count requests
        if self.fault == "shapes":
            outputs = {k: v[..., :-1] for k, v in outputs.items()}
        return self._reply(outputs, wanted)

    def _reply(self, outputs: dict[str, np.ndarray], wanted: dict[str, bool]) -> None:
        header, blobs = {"model_name": "m", "outputs": []}, []
        for name, array in outputs.items():
            if wanted and name not in wanted:
                continue
            array = np.ascontiguousarray(array)
            out = {"name": name, "datatype": NAMES[array.dtype.type], "shape": list(array.shape)}
            if wanted.get(name, False):
                blobs.append(array.tobytes())
                out["parameters"] = {"binary_data_size": len(blobs[-1])}
            else:
                out["data"] = array.reshape(-1).tolist()
            header["outputs"].append(out)
        head = json.dumps(header).encode()
        headers = {"Content-Type": "application/octet-stream" if blobs else "application/json"}
        if blobs:
            headers["Inference-Header-Content-Length"] = str(len(head))
        self._send(200, head + b"".join(blobs), headers)


def parse_request(body: bytes, headers) -> tuple[dict[str, np.ndarray], dict[str, bool]]:
    """The inputs of an inference request (JSON data or binary tensors after the JSON header) and the outputs
    asked for (name -> binary)."""
    size = int(headers.get("Inference-Header-Content-Length") or len(body))
    request = json.loads(body[:size])
    offset, feeds = size, {}
    for inp in request["inputs"]:
        dtype = TYPES[inp["datatype"]]
        nbytes = (inp.get("parameters") or {}).get("binary_data_size")
        if nbytes is not None:
            data = np.frombuffer(body[offset:offset + nbytes], dtype=dtype)
            offset += nbytes
        else:
            data = np.asarray(inp["data"], dtype=dtype)
        feeds[inp["name"]] = data.reshape(inp["shape"])
    default = bool((request.get("parameters") or {}).get("binary_data_output", False))
    wanted = {o["name"]: bool((o.get("parameters") or {}).get("binary_data", default))
              for o in request.get("outputs") or []}
    return feeds, wanted


def brightness_onnx(path: Path, names=("car", "person")) -> Path:
    """A tiny detection graph with the boxes/scores/classes outputs, whose answer a test can compute by hand:
    for each UINT8 N x H x W x 3 frame, K = 2 rows: a "car" at (10, 20, 110, 220) scored by the frame's mean
    brightness / 255, then a padding row (score 0)."""
    import onnx
    from onnx import TensorProto, helper

    const = lambda name, values: helper.make_tensor(name, TensorProto.FLOAT, np.shape(values),  # noqa: E731
                                                    np.asarray(values, np.float32).reshape(-1).tolist())
    nodes = [
        helper.make_node("Cast", ["images"], ["x"], to=TensorProto.FLOAT),
        helper.make_node("ReduceMean", ["x", "axes"], ["mean"], keepdims=0),  # N
        helper.make_node("Reshape", ["mean", "col"], ["m"]),  # N x 1
        helper.make_node("Mul", ["m", "score_k"], ["scores"]),  # N x 2
        helper.make_node("Mul", ["m", "zero"], ["z"]),
        helper.make_node("Add", ["z", "class_k"], ["classes"]),  # N x 2
        helper.make_node("Reshape", ["z", "col3"], ["z3"]),  # N x 1 x 1
        helper.make_node("Add", ["z3", "box_k"], ["boxes"]),  # N x 2 x 4
    ]
    inits = [helper.make_tensor("axes", TensorProto.INT64, [3], [1, 2, 3]),
             helper.make_tensor("col", TensorProto.INT64, [2], [-1, 1]),
             helper.make_tensor("col3", TensorProto.INT64, [3], [-1, 1, 1]),
             const("score_k", [[1 / 255, 0.0]]), const("zero", [[0.0]]), const("class_k", [[0.0, 1.0]]),
             const("box_k", [[[10, 20, 110, 220], [0, 0, 0, 0]]])]
    graph = helper.make_graph(
        nodes, "brightness", [helper.make_tensor_value_info("images", TensorProto.UINT8, ["N", "H", "W", 3])],
        [helper.make_tensor_value_info("boxes", TensorProto.FLOAT, ["N", 2, 4]),
         helper.make_tensor_value_info("scores", TensorProto.FLOAT, ["N", 2]),
         helper.make_tensor_value_info("classes", TensorProto.FLOAT, ["N", 2])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    helper.set_model_props(model, {"names": json.dumps(list(names))})
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


class Server:
    """This server as a child process in its own session on a free port; `stop()` kills it by its pid (call
    it in a finally: it is safe to call twice or after the process died)."""

    def __init__(self, models: dict[str, Path], fault: str = "", log: Path | None = None):
        import socket

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.models, self.fault, self.log = models, fault, log
        self.proc = None
        self.command = [sys.executable, __file__]  # the server's program (tests/kserve_stock.py: kserve's own)

    def url(self, name: str) -> str:
        return f"http://127.0.0.1:{self.port}/v2/models/{name}"

    def start(self, timeout: float = 60.0) -> "Server":
        import subprocess
        import time
        import urllib.request

        args = [*self.command, str(self.port), *(f"{k}={v}" for k, v in self.models.items())]
        if self.fault:
            args += ["--fault", self.fault]
        out = open(self.log, "a") if self.log else subprocess.DEVNULL
        self.proc = subprocess.Popen(args, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + timeout
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/v2/health/ready", timeout=2) as r:
                    if r.status == 200:
                        return self
            except OSError:
                pass
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"the test model server did not come up (exit {self.proc.returncode})")
            time.sleep(0.2)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)  # its own session: the group is this server alone
        if self.proc is not None:
            self.proc.wait(timeout=30)

    def __enter__(self) -> "Server":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def main(argv: list[str]) -> None:
    port, *specs = argv
    fault = ""
    if "--fault" in specs:
        k = specs.index("--fault")
        fault = specs[k + 1]
        del specs[k:k + 2]
    models = {}
    for spec in specs:
        name, path = spec.split("=", 1)
        path = Path(path)
        models[name] = OpenVinoModel(path) if path.is_dir() else OnnxModel(path)
    Handler.models, Handler.fault = models, fault
    server = ThreadingHTTPServer(("127.0.0.1", int(port)), Handler)
    server.daemon_threads = True
    print(f"serving {sorted(models)} on {port}", flush=True)
    server.serve_forever()


if __name__ == "__main__":
    main(sys.argv[1:])
