"""A stock KServe server, as a user deploys one: a plain `kserve.Model` serving an ONNX detector through onnxruntime,
behind kserve's own REST server (kserve 0.21, its FastAPI app and uvicorn). Not a server this project wrote: its
metadata has no `parameters` and it has no `/v2/models/NAME/config` route, so it cannot say the class names.

    .venv-kserve/bin/python tests/kserve_stock.py PORT NAME=MODEL.onnx [NAME=MODEL.onnx ...]

kserve pins a protobuf, pandas and psutil older than the project's, so it runs from its own environment,
.venv-kserve (`make python` makes it from requirements-kserve.txt). It binds 127.0.0.1 only: kserve's RESTServer
hard-codes 0.0.0.0 in its uvicorn Config, which is changed before the server starts. tests/test_kserve_stock.py
starts it and stops it by its pid; docs/perception.md shows the same model served by hand.
"""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

import numpy as np
import onnxruntime as ort
from kserve import InferOutput, InferRequest, InferResponse, Model, ModelServer
from kserve.model_server import FASTAPI_APP_IMPORT_STRING
from kserve.protocol.rest.server import RESTServer

TYPES = {"tensor(float)": "FP32", "tensor(uint8)": "UINT8"}  # onnxruntime's tensor types -> the protocol's
DATATYPES = {np.dtype(np.float32): "FP32", np.dtype(np.uint8): "UINT8"}


class OnnxDetector(Model):
    """One ONNX graph (e.g. an ultralytics export of yolo11n: FP32 N x 3 x 640 x 640 in, its raw head out)."""

    def __init__(self, name: str, path: Path):
        super().__init__(name)
        self.path = path
        self.session = None

    def load(self) -> bool:
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        self.session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        self.ready = True
        return self.ready

    def get_input_types(self) -> list[dict]:
        return [_tensor(i) for i in self.session.get_inputs()]

    def get_output_types(self) -> list[dict]:
        return [_tensor(o) for o in self.session.get_outputs()]

    async def predict(self, payload: InferRequest, headers=None, response_headers=None) -> InferResponse:
        feeds = {i.name: i.as_numpy() for i in payload.inputs}
        names = [o.name for o in self.session.get_outputs()]
        outputs = []
        for name, array in zip(names, self.session.run(names, feeds)):
            out = InferOutput(name=name, shape=list(array.shape), datatype=DATATYPES[array.dtype])
            out.set_data_from_numpy(array, binary_data=True)
            outputs.append(out)
        return InferResponse(response_id=payload.id or "0", model_name=self.name, infer_outputs=outputs,
                             use_binary_outputs=True)


def _tensor(arg) -> dict:
    return {"name": arg.name, "datatype": TYPES[arg.type],
            "shape": [d if isinstance(d, int) else -1 for d in arg.shape]}


def main(port: int, models: list[tuple[str, Path]]) -> None:
    server = ModelServer(http_port=port, enable_grpc=False, workers=1)
    for name, path in models:
        model = OnnxDetector(name, path)
        model.load()
        server.register_model(model)
    rest = RESTServer(FASTAPI_APP_IMPORT_STRING, server.dataplane, server.model_repository_extension, port)
    rest.config.host = "127.0.0.1"  # kserve's own default is every interface
    asyncio.run(rest.start())


if __name__ == "__main__":
    pairs = [a.split("=", 1) for a in sys.argv[2:]]
    main(int(sys.argv[1]), [(name, Path(path)) for name, path in pairs])
