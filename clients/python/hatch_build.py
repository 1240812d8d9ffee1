"""Build hooks (hatchling): the gRPC stubs are generated from the repository's proto/ into a
temporary directory and added to the wheel from there, so building or installing the client
writes nothing into the source tree (no build/, no egg-info, no generated modules).

The stubs are never committed. The proto directory is $TRINOCULAR_PROTO_DIR, else ../../proto
(the repository's), else ./proto (the copy an sdist carries). grpcio and protobuf are required
at least at the versions of the grpcio-tools that generated the stubs: generated code refuses
older runtimes.
"""

import os
import shutil
import subprocess
import sys
import tempfile
from importlib.metadata import version
from pathlib import Path

from hatchling.builders.hooks.plugin.interface import BuildHookInterface
from hatchling.metadata.plugin.interface import MetadataHookInterface

PROTO_REL = Path("trinocular") / "v1" / "trinocular.proto"


def proto_dir(root: Path) -> Path:
    candidates = [os.environ.get("TRINOCULAR_PROTO_DIR"), root / ".." / ".." / "proto", root / "proto"]
    for c in candidates:
        if c and (Path(c) / PROTO_REL).is_file():
            return Path(c).resolve()
    raise RuntimeError(f"cannot find {PROTO_REL}: set TRINOCULAR_PROTO_DIR or build from the repository")


def generate(proto: Path, out_root: Path) -> Path:
    """Writes trinocular/v1/{__init__,trinocular_pb2,trinocular_pb2_grpc}.py(i) under out_root."""
    cmd = [
        sys.executable, "-m", "grpc_tools.protoc", f"-I{proto}",
        f"--python_out={out_root}", f"--pyi_out={out_root}", f"--grpc_python_out={out_root}",
        str(proto / PROTO_REL),
    ]
    subprocess.run(cmd, check=True)
    gen = out_root / "trinocular" / "v1"
    (gen / "__init__.py").write_text('"""Generated gRPC stubs (do not edit, not committed)."""\n')
    grpc_file = gen / "trinocular_pb2_grpc.py"
    text = grpc_file.read_text()
    # protoc writes an absolute import; the package may be vendored under another name.
    grpc_file.write_text(
        text.replace("from trinocular.v1 import trinocular_pb2 as", "from . import trinocular_pb2 as")
    )
    return gen


class StubsBuildHook(BuildHookInterface):
    PLUGIN_NAME = "custom"

    def initialize(self, version_: str, build_data: dict) -> None:
        root = Path(self.root)
        if self.target_name == "sdist":
            # An sdist carries the proto so that a wheel can be built from it alone.
            build_data["force_include"][str(proto_dir(root) / PROTO_REL)] = str(Path("proto") / PROTO_REL)
            return
        self._tmp = Path(tempfile.mkdtemp(prefix="trinocular-stubs-"))
        gen = generate(proto_dir(root), self._tmp)
        for f in sorted(gen.iterdir()):
            dest = f"trinocular/v1/{f.name}"
            build_data["force_include"][str(f)] = dest
            # An editable install points at src/ and gets the stubs into site-packages.
            build_data.setdefault("force_include_editable", {})[str(f)] = dest

    def finalize(self, version_: str, build_data: dict, artifact_path: str) -> None:
        tmp = getattr(self, "_tmp", None)
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


class RuntimeFloorsMetadataHook(MetadataHookInterface):
    PLUGIN_NAME = "custom"

    def update(self, metadata: dict) -> None:
        metadata["dependencies"] = [
            f"grpcio>={version('grpcio-tools')}",
            f"protobuf>={version('protobuf')}",
            "numpy>=1.21",
        ]
