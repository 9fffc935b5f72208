#!/usr/bin/env python3
"""Call ilqr-service over gRPC with grpcio: list the models, solve, stream.

The stubs are generated from ``proto/ilqr/v1/ilqr.proto`` by grpcio-tools
when the script starts (into a temporary directory), so nothing generated
is committed and the stubs always match the contract. This script

1. lists the models (``ListModels``);
2. solves the problem given as JSON (default: ``{}``, the seed scenario)
   with ``Solve`` under a deadline, and prints status, cost and iterations;
3. solves it again with ``SolveStream``, printing each iteration's cost as
   it arrives;
4. sends an invalid problem and prints the ``google.rpc.BadRequest`` field
   violations the service answers with.

Usage (with a service running, gRPC on 50051 by default)::

    pip install grpcio grpcio-tools grpcio-status
    python3 examples/grpc_client.py                        # localhost:50051
    python3 examples/grpc_client.py --target host:50051 --problem examples/unicycle.json

Exit status: 0 on success, 1 on a failure to reach or use the service.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any, Dict, Tuple

REPO = Path(__file__).resolve().parents[1]
PROTO_ROOT = REPO / "proto"
PROTO = "ilqr/v1/ilqr.proto"


def load_stubs(out_dir: Path) -> Tuple[ModuleType, ModuleType]:
    """Generate the Python stubs of the contract into ``out_dir`` and import
    them: ``(ilqr_pb2, ilqr_pb2_grpc)``."""
    from grpc_tools import protoc

    status = protoc.main(
        [
            "grpc_tools.protoc",
            f"-I{PROTO_ROOT}",
            f"--python_out={out_dir}",
            f"--grpc_python_out={out_dir}",
            str(PROTO_ROOT / PROTO),
        ]
    )
    if status != 0:
        raise RuntimeError(f"grpc_tools.protoc failed on {PROTO_ROOT / PROTO} ({status})")
    sys.path.insert(0, str(out_dir))
    return (
        importlib.import_module("ilqr.v1.ilqr_pb2"),
        importlib.import_module("ilqr.v1.ilqr_pb2_grpc"),
    )


def problem_message(pb2: ModuleType, doc: Dict[str, Any]) -> Any:
    """The JSON problem ``doc`` as an ``ilqr.v1.Problem``: the members
    this example uses (model, integrator, dt, horizon, states, weights,
    obstacles, solver). Matrices are flat, row after row."""
    p = pb2.Problem()
    model = doc.get("model") or {}
    if model:
        if "type" in model:
            p.model.type = model["type"]
        for name, value in model.items():
            if name != "type":
                p.model.parameters[name] = float(value)
    if "integrator" in doc:
        p.integrator = {"euler": pb2.INTEGRATOR_EULER, "rk4": pb2.INTEGRATOR_RK4}[doc["integrator"]]
    for member in ("dt", "horizon"):
        if member in doc:
            setattr(p, member, doc[member])
    p.initial_state.extend(doc.get("initial_state", []))
    p.goal_state.extend(doc.get("goal_state", []))
    for member, values in (doc.get("weights") or {}).items():
        getattr(p.weights, member).extend(values)
    if "obstacles" in doc:
        p.obstacles.SetInParent()
        for o in doc["obstacles"]:
            item = p.obstacles.items.add()
            item.center.extend(o["center"])
            if "weight" in o:
                item.weight = o["weight"]
    for row in doc.get("initial_controls") or []:
        p.initial_controls.extend(row)
    solver = doc.get("solver") or {}
    for member in ("max_iterations", "tolerance", "time_limit_ms"):
        if member in solver:
            setattr(p.solver, member, solver[member])
    return p


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--target", default="localhost:50051", help="host:port of the gRPC server")
    parser.add_argument("--problem", type=Path, help="a JSON problem file (default: {})")
    parser.add_argument("--deadline", type=float, default=10.0, help="seconds per call")
    args = parser.parse_args()

    import grpc
    from google.rpc import error_details_pb2
    from grpc_status import rpc_status

    doc = json.loads(args.problem.read_text()) if args.problem else {}
    with tempfile.TemporaryDirectory() as stubs:
        pb2, pb2_grpc = load_stubs(Path(stubs))
        with grpc.insecure_channel(args.target) as channel:
            stub = pb2_grpc.TrajectoryOptimizerStub(channel)
            try:
                models = stub.ListModels(pb2.ListModelsRequest(), timeout=args.deadline)
                for m in models.models:
                    print(f"model {m.type}: {len(m.state)} states, {len(m.control)} controls")

                problem = problem_message(pb2, doc)
                answer = stub.Solve(pb2.SolveRequest(problem=problem), timeout=args.deadline)
                r = answer.result
                status = pb2.SolveStatus.Name(r.status)
                print(f"solve: {status}, cost {r.cost:.6f}, {r.iterations} iterations")

                for event in stub.SolveStream(pb2.SolveRequest(problem=problem), timeout=args.deadline):
                    if event.HasField("iteration"):
                        print(f"  iteration {event.iteration.iteration}: cost {event.iteration.cost:.6f}")
                    else:
                        print(f"stream: {pb2.SolveStatus.Name(event.result.status)}, cost {event.result.cost:.6f}")

                bad = pb2.Problem(dt=-1.0, initial_state=[0.0, 0.0])
                try:
                    stub.Solve(pb2.SolveRequest(problem=bad), timeout=args.deadline)
                except grpc.RpcError as e:
                    print(f"invalid problem: {e.code().name}")
                    status_proto = rpc_status.from_call(e)
                    for detail in status_proto.details if status_proto else []:
                        if detail.Is(error_details_pb2.BadRequest.DESCRIPTOR):
                            bad_request = error_details_pb2.BadRequest()
                            detail.Unpack(bad_request)
                            for v in bad_request.field_violations:
                                print(f"  {v.field}: {v.description}")
            except grpc.RpcError as e:
                print(f"error: {e.code().name}: {e.details()}", file=sys.stderr)
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
