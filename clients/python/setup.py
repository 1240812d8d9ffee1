"""Build hook: generates the gRPC stubs from ../../proto at build/install time.

The stubs are never committed. `build_py` runs `python -m grpc_tools.protoc` (grpcio-tools is
a build requirement) into the package's `trinocular/v1/` and makes the generated import
package-relative. The proto directory is $TRINOCULAR_PROTO_DIR, else ../../proto (the repo's),
else ./proto (a copy, e.g. in an sdist).
"""

import os
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

HERE = Path(__file__).resolve().parent
PROTO_REL = Path("trinocular") / "v1" / "trinocular.proto"


def proto_dir() -> Path:
    candidates = [os.environ.get("TRINOCULAR_PROTO_DIR"), HERE / ".." / ".." / "proto", HERE / "proto"]
    for c in candidates:
        if c and (Path(c) / PROTO_REL).is_file():
            return Path(c).resolve()
    raise RuntimeError(
        f"cannot find {PROTO_REL}: set TRINOCULAR_PROTO_DIR or build from the repository"
    )


def generate(out_root: Path) -> None:
    """Writes trinocular/v1/{__init__,trinocular_pb2,trinocular_pb2_grpc}.py under out_root."""
    src = proto_dir()
    out_root.mkdir(parents=True, exist_ok=True)
    cmd = [
        sys.executable, "-m", "grpc_tools.protoc", f"-I{src}",
        f"--python_out={out_root}", f"--pyi_out={out_root}", f"--grpc_python_out={out_root}",
        str(src / PROTO_REL),
    ]
    subprocess.run(cmd, check=True)
    gen = out_root / "trinocular" / "v1"
    (gen / "__init__.py").write_text('"""Generated gRPC stubs (do not edit, not committed)."""\n')
    grpc_file = gen / "trinocular_pb2_grpc.py"
    text = grpc_file.read_text()
    text = text.replace(
        "from trinocular.v1 import trinocular_pb2 as", "from . import trinocular_pb2 as"
    )
    grpc_file.write_text(text)


class BuildPyWithStubs(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            generate(HERE / "src")  # editable: next to the sources (git-ignored)
        else:
            generate(Path(self.build_lib))


class SdistWithProto(sdist):
    def make_release_tree(self, base_dir, files):
        super().make_release_tree(base_dir, files)
        dst = Path(base_dir) / "proto" / PROTO_REL
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_bytes((proto_dir() / PROTO_REL).read_bytes())


setup(
    cmdclass={"build_py": BuildPyWithStubs, "sdist": SdistWithProto},
    install_requires=[
        f"grpcio>={version('grpcio-tools')}",
        f"protobuf>={version('protobuf')}",
        "numpy>=1.21",
    ],
)
