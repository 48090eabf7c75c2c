"""Node programs as plain data: what a material's node tree compiles to (engine/export/nodes.py) and the
kernel runs over a wave's hits (kernels/shading/program.py), as Cycles compiles a shader graph to SVM.

A program is a list of ops in dependency order. Each op is one shader node: its kind (OPS in
kernels/shading/ops.py), its inputs (a constant after folding, or a Ref to an earlier op's output) and its
options (Blender's enum identifiers and plain values). Closure inputs (kernels.scene.Param) point into
their material's program with a Ref.

Socket types are Blender's: VALUE (N,) float32, VECTOR and RGBA (N, 3) float32. A Ref carries the type of
the output and the type the consumer wants; the runner converts between them as Blender does (colour to
float by luminance, vector to float by the average, float to vector or colour by splatting).
"""
from __future__ import annotations

from dataclasses import dataclass

SOCKET_TYPES = ("VALUE", "VECTOR", "RGBA")


@dataclass(frozen=True)
class Ref:
    """An op's output, as one of its consumers reads it.

    op : index of the op in Program.ops.
    output : the output socket's identifier (as Blender names it: "Color", "Fac", "Vector", ...).
    type : the output's socket type; want : the type the consumer reads (the runner converts).
    """
    op: int
    output: str
    type: str = "VALUE"
    want: str = "VALUE"


@dataclass(frozen=True)
class Op:
    """One node of a program.

    kind : the op's name in kernels/shading/ops.OPS.
    inputs : ((name, value), ...): value a Ref, or a constant tuple of 1 (VALUE) or 3 floats.
    options : ((name, value), ...) of hashable plain values (strings, numbers, tuples, texture indices).
    """
    kind: str
    inputs: tuple = ()
    options: tuple = ()

    def option(self, name: str, default=None):
        return next((v for k, v in self.options if k == name), default)


@dataclass(frozen=True)
class Program:
    """A material's ops, in dependency order (an op reads only earlier ops)."""
    ops: tuple = ()

    def __len__(self) -> int:
        return len(self.ops)

    def validate(self, n_textures: int) -> None:
        for i, op in enumerate(self.ops):
            for name, value in op.inputs:
                if isinstance(value, Ref):
                    if not 0 <= value.op < i:
                        raise ValueError(f"program op {i} ({op.kind}) input {name} reads op {value.op}, "
                                         f"which is not an earlier op")
                    if value.type not in SOCKET_TYPES or value.want not in SOCKET_TYPES:
                        raise ValueError(f"program op {i} ({op.kind}) input {name}: unknown socket type")
                elif not (isinstance(value, tuple) and len(value) in (1, 3)):
                    raise ValueError(f"program op {i} ({op.kind}) input {name}: a constant must be a tuple "
                                     f"of 1 or 3 floats, got {value!r}")
            texture = op.option("texture")
            if texture is not None and not -1 <= texture < n_textures:
                raise ValueError(f"program op {i} ({op.kind}) reads texture {texture} of {n_textures}")
            for tile, index in op.option("tiles", ()):
                if not (1001 <= tile and 0 <= index < n_textures):
                    raise ValueError(f"program op {i} ({op.kind}) reads UDIM tile {tile} from texture {index} of "
                                     f"{n_textures}")
