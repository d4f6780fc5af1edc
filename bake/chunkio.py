"""Traced chunk files: the arrays one worker computed for one chunk of points.

A chunk file is a run of ``.npy`` records (numpy's own format): first the array names, then
one array per name, each with the chunk's points along axis 0. Not ``.npz``: ``np.savez``
writes a zip whose CRC-32 over every byte took a visible share of the workers' time
(docs/benchmarks.md, "Baking"), and reading a set back from zips, then concatenating its
chunks, copied every array twice. Here each chunk's arrays are read straight into their
rows of the set's arrays.

Files are written under a temporary name and renamed when complete: a chunk file that exists
is whole (an interrupted bake resumes from them).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

SUFFIX = ".chunk"


def save_chunk(path: Path, arrays: dict) -> None:
    """Write ``{name: array}`` to ``path`` (temporary name first, then renamed)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    names = sorted(arrays)
    with open(tmp, "wb") as f:
        np.save(f, np.array(names, dtype=str))
        for name in names:
            np.save(f, np.ascontiguousarray(arrays[name]))
    os.replace(tmp, path)


def load_chunks(paths: list[Path], columns: slice | None = None, names=None) -> dict:
    """Every array of the chunk files ``paths``, each chunk's rows after the previous one's:
    ``{name: (sum of rows, ...)}``. The files must hold the same names, shapes beyond axis 0
    and dtypes. ``columns``: only these of axis 1 (the lights: a block of them, so that a
    set's arrays are not all held at once, docs/benchmarks.md "The write stage's memory");
    ``names``: only these arrays (those the chunks hold)."""
    layouts = [_layout(path) for path in paths]
    if names is not None:
        layouts = [{k: v for k, v in layout.items() if k in names} for layout in layouts]
    for path, layout in zip(paths[1:], layouts[1:], strict=True):
        if layout.keys() != layouts[0].keys():
            raise ValueError(f"{path} holds {sorted(layout)}, {paths[0]} {sorted(layouts[0])}")
    out = {}
    for name, (shape, dtype, _) in (layouts[0] if layouts else {}).items():
        rows = sum(layout[name][0][0] for layout in layouts)
        width = shape[1:] if columns is None else (len(range(shape[1])[columns]),) + shape[2:]
        out[name] = np.empty((rows,) + width, dtype=dtype)
    row = dict.fromkeys(out, 0)
    for path, layout in zip(paths, layouts, strict=True):
        with open(path, "rb") as f:
            for name, (shape, dtype, offset) in layout.items():
                if shape[1:] != layouts[0][name][0][1:] or dtype != out[name].dtype:
                    raise ValueError(f"{path}: {name} {shape} {dtype} does not match the others")
                target = out[name][row[name] : row[name] + shape[0]]
                # A block of columns is read whole, then its columns copied: one chunk's rows.
                whole = target if columns is None else np.empty(shape, dtype=dtype)
                f.seek(offset)
                if f.readinto(memoryview(whole).cast("B")) != whole.nbytes:
                    raise ValueError(f"{path} is truncated (in {name})")
                if columns is not None:
                    target[...] = whole[:, columns]
                row[name] += shape[0]
    return out


def _layout(path: Path) -> dict:
    """``{name: (shape, dtype, byte offset of the data)}`` of one chunk file."""
    with open(path, "rb") as f:
        names = np.load(f)
        layout = {}
        for name in names:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
            else:
                raise ValueError(f"{path}: .npy format {version} is not written by save_chunk")
            if fortran:
                raise ValueError(f"{path}: {name} is not C-ordered")
            layout[str(name)] = (shape, dtype, f.tell())
            f.seek(int(np.prod(shape)) * dtype.itemsize, os.SEEK_CUR)
    return layout
