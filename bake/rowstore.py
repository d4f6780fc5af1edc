"""Arrays of the write stage kept on disk and read by blocks of rows (issue 20: no step of a
bake holds all lights x all texels in memory at once).

A stack of a large site is lights x texels: at 400 lights the palace's hull stack alone is
6.8 GB of float32 (docs/benchmarks.md, "The write stage's memory"). The write stage assembles
a stack by blocks of lights (the bounce's smoothing is spatial: it needs whole images) and
compresses it by blocks of texels (every product of bake.lowrank is row-wise), so a stack
is written to disk block by block and read back by rows:

- :class:`RowFile` is one C-ordered array in a ``.npy`` file (numpy's own format, so
  ``np.load`` opens it), written and read by rows with plain file I/O. Not a memory map: the
  pages of a mapped file count in the process's resident memory for as long as they stay
  mapped, and a pass over a stack would map all of it.
- :class:`StackStore` is a stack ``(H, W, n, 3)`` written by blocks of lights: one
  :class:`RowFile` ``(H * W, b, 3)`` per block, so that a block is one sequential write and a
  run of texel rows of all lights is one read per block.
- :func:`rows_of` reads rows of either, or of an array in memory (small stacks, tests).

What is read is a fresh array: the caller's block is all that is held.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from pathlib import Path

import numpy as np

# Bytes of one working block of rows (of every light): each block-wise pass over a stack
# holds a few arrays of this size. 64 MB: a few hundred texel rows of a 400-light stack at
# the least, thousands at 40 lights.
ROW_BLOCK_BYTES = 64 << 20


class RowFile:
    """An array of ``shape`` and ``dtype`` in the ``.npy`` file ``path``, C-ordered, written
    and read by rows (axis 0). Create it with :meth:`create`, or open an existing one."""

    def __init__(self, path: Path | str):
        self.path = Path(path)
        with open(self.path, "rb") as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
            else:
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
            self.offset = f.tell()
        if fortran:
            raise ValueError(f"{self.path} is not C-ordered")
        self.shape, self.dtype = tuple(shape), np.dtype(dtype)
        self.row_bytes = int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize

    @classmethod
    def create(cls, path: Path | str, shape: tuple, dtype=np.float32) -> RowFile:
        """A new file of ``shape`` (zeros until written: a sparse file)."""
        path = Path(path)
        header = {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)),
                  "fortran_order": False, "shape": tuple(int(s) for s in shape)}
        with open(path, "wb") as f:
            np.lib.format.write_array_header_2_0(f, header)
            f.truncate(f.tell() + int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize)
        return cls(path)

    def __len__(self) -> int:
        return self.shape[0]

    def write(self, start: int, block: np.ndarray) -> None:
        """Rows ``start .. start + len(block)`` from ``block`` (shape ``(b,) + shape[1:]``)."""
        block = np.ascontiguousarray(block, dtype=self.dtype)
        if block.shape[1:] != self.shape[1:] or start < 0 or start + len(block) > len(self):
            raise ValueError(f"rows {start}+{block.shape} do not fit {self.path} {self.shape}")
        with open(self.path, "r+b") as f:
            f.seek(self.offset + start * self.row_bytes)
            f.write(memoryview(block).cast("B"))

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start .. stop`` as a new array."""
        start, stop = max(0, start), min(stop, len(self))
        out = np.empty((max(stop - start, 0),) + self.shape[1:], dtype=self.dtype)
        if out.nbytes:
            with open(self.path, "rb") as f:
                f.seek(self.offset + start * self.row_bytes)
                if f.readinto(memoryview(out).cast("B")) != out.nbytes:
                    raise ValueError(f"{self.path} is truncated")
        return out

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)


class StackStore:
    """A stack ``(H, W, n, 3)`` float32 on disk, written by blocks of lights (one
    :class:`RowFile` ``(H * W, b, 3)`` per block, in ``folder``) and read by rows of texels
    (:meth:`rows`) or by single lights (:meth:`column`). ``valid`` (H, W) is where any light
    is non-zero, gathered as the blocks are written."""

    def __init__(self, folder: Path | str, height: int, width: int, n: int):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.height, self.width, self.n = height, width, n
        self.blocks: list[tuple[slice, RowFile]] = []
        self.valid = np.zeros((height, width), dtype=bool)

    @property
    def shape(self) -> tuple:
        return (self.height, self.width, self.n, 3)

    @property
    def work(self) -> Path:
        """Where what is made from the stack goes (its spectrum: bake.compress)."""
        return self.folder.parent

    @property
    def texels(self) -> int:
        return self.height * self.width

    def write_block(self, lights: slice, image: np.ndarray) -> None:
        """The lights ``lights`` (the next block, in order) as ``image`` (H, W, b, 3)."""
        start = self.blocks[-1][0].stop if self.blocks else 0
        if lights.start != start or image.shape != (self.height, self.width,
                                                     lights.stop - lights.start, 3):
            raise ValueError(f"block {lights} of shape {image.shape} does not follow {start}")
        f = RowFile.create(self.folder / f"L{lights.start:04d}-{lights.stop:04d}.npy",
                           (self.texels, lights.stop - lights.start, 3))
        f.write(0, image.reshape(self.texels, -1, 3))
        self.valid |= np.any(image != 0.0, axis=(2, 3))
        self.blocks.append((lights, f))

    def complete(self) -> bool:
        return bool(self.blocks) and self.blocks[-1][0].stop == self.n

    def rows(self, start: int, stop: int) -> np.ndarray:
        """Texel rows ``start .. stop`` (of the H * W, row-major) of every light:
        ``(stop - start, n, 3)``."""
        stop = min(stop, self.texels)
        out = np.empty((max(stop - start, 0), self.n, 3), dtype=np.float32)
        for lights, f in self.blocks:
            out[:, lights] = f.read(start, stop)
        return out

    def column(self, light: int) -> np.ndarray:
        """Light ``light``'s image (H, W, 3)."""
        return self.columns([light])[0]

    def columns(self, lights) -> np.ndarray:
        """The images of ``lights`` (len(lights), H, W, 3), each block file read once."""
        lights = [int(i) for i in lights]
        out = np.empty((len(lights), self.texels, 3), dtype=np.float32)
        for block, f in self.blocks:
            wanted = [(j, i - block.start) for j, i in enumerate(lights)
                      if block.start <= i < block.stop]
            if not wanted:
                continue
            targets, sources = (list(x) for x in zip(*wanted, strict=True))
            step = row_block(f.shape[1])
            for start in range(0, self.texels, step):
                rows = f.read(start, start + step)
                out[targets, start : start + len(rows)] = rows[:, sources].transpose(1, 0, 2)
        missing = [i for i in lights if not 0 <= i < self.n]
        if missing:
            raise IndexError(f"lights {missing} are not in the stack (n = {self.n})")
        return out.reshape(len(lights), self.height, self.width, 3)

    def array(self) -> np.ndarray:
        """The whole stack in memory (H, W, n, 3): for a cluster's workers and tests."""
        return self.rows(0, self.texels).reshape(self.shape)

    def remove(self) -> None:
        for _, f in self.blocks:
            f.remove()
        self.blocks = []


class ArrayStack:
    """A stack ``(H, W, n, 3)`` given as an array (a fixed view's, a test's), read as a
    :class:`StackStore` is. A memory-mapped one (``np.memmap``, ``np.load(mmap_mode=...)``)
    is read by rows too, and what is made from it goes to disk beside it (:attr:`work`)."""

    def __init__(self, image: np.ndarray):
        self.image = image
        self.height, self.width, self.n, _ = image.shape
        mapped = getattr(image, "filename", None)
        self.work = None if mapped is None else Path(mapped).parent
        # By rows: ``image != 0`` whole would be a byte per value (a quarter of the stack).
        flat = image.reshape(self.texels, self.n, 3)
        step = row_block(self.n)
        self.valid = np.concatenate(
            [np.any(flat[a : a + step] != 0.0, axis=(1, 2)) for a in range(0, self.texels, step)]
            or [np.zeros(0, bool)]
        ).reshape(self.height, self.width)

    shape = StackStore.shape
    texels = StackStore.texels

    def rows(self, start: int, stop: int) -> np.ndarray:
        return self.image.reshape(self.texels, self.n, 3)[start:stop]

    def column(self, light: int) -> np.ndarray:
        return self.image[:, :, light]

    def columns(self, lights) -> np.ndarray:
        return np.ascontiguousarray(self.image[:, :, list(lights)].transpose(2, 0, 1, 3))

    def array(self) -> np.ndarray:
        return self.image

    def remove(self) -> None:
        self.image = None


def as_stack(stack):
    """A :class:`StackStore` or :class:`ArrayStack` as it is; an array (H, W, n, 3) as an
    :class:`ArrayStack`."""
    if isinstance(stack, (StackStore, ArrayStack)) or hasattr(stack, "columns"):
        return stack  # a stack read by columns (bake.sunshare.SharedColumns) as well
    return ArrayStack(stack)


def valid_blocks(stacks, valid: np.ndarray):
    """The valid texels of ``stacks`` (each with ``rows``, the same texels) by blocks of rows
    (:func:`row_block` of the first's n): yields ``(t, [rows (b, n, 3) of each stack at the
    block's valid texels])``, t the first one's index among the valid texels. The list is
    the caller's alone (nothing here keeps it), so a caller may let it go before working."""
    first = stacks[0]
    flat = valid.ravel()
    step = row_block(first.n)
    t = 0
    for a in range(0, first.texels, step):
        keep = flat[a : a + step]
        if not keep.any():
            continue
        yield t, [s.rows(a, a + step)[keep] for s in stacks]
        t += int(keep.sum())


def valid_rows(stacks, valid: np.ndarray, make, names: list[str]) -> list:
    """The valid texels of ``stacks`` (each with ``rows``, :mod:`bake.rowstore`) as made by
    ``make(*rows of each stack at the valid texels, first texel index)`` -> one array
    (b, n, 3) per name of ``names``: in memory for stacks in memory, else one
    :class:`RowFile` each in the first stack's ``work`` folder (``<name>.npy``), written by
    blocks of rows."""
    first = stacks[0]
    T = int(valid.sum())
    on_disk = first.work is not None
    out = [
        RowFile.create(first.work / f"{name}.npy", (T, first.n, 3)) if on_disk
        else np.empty((T, first.n, 3), dtype=np.float32)
        for name in names
    ]
    for t, rows in valid_blocks(stacks, valid):
        made = make(*rows, t)
        made = made if isinstance(made, tuple) else (made,)
        for target, block in zip(out, made, strict=True):
            if on_disk:
                target.write(t, block)
            else:
                target[t : t + len(block)] = block
    return out


def let_go(*stacks) -> None:
    """Remove stores from disk once their valid texels are gathered (an array in memory is
    the caller's)."""
    for stack in stacks:
        if isinstance(stack, StackStore):
            stack.remove()


def release_freed_memory() -> None:
    """Give the heap's free pages back to the system (glibc's ``malloc_trim``; nothing
    elsewhere). Arrays below glibc's mmap threshold (up to 32 MB) come from the heap, and
    once freed their pages stay in the process's resident memory: after the receivers and
    the tracing 0.4 GB of the palace bake's 0.95 GB was such pages (docs/benchmarks.md,
    "The write stage's memory")."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def _libc():
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    return libc if libc is not None and hasattr(libc, "malloc_trim") else None


_LIBC = _libc()


def row_block(n: int, itemsize: int = 4, budget: int | None = None) -> int:
    """Rows of ``n`` lights x 3 channels of ``itemsize`` bytes that fit a working block of
    ``budget`` bytes (default :data:`ROW_BLOCK_BYTES`); at least 256."""
    budget = ROW_BLOCK_BYTES if budget is None else budget
    return max(256, budget // max(1, n * 3 * itemsize))


def rows_of(source, start: int, stop: int) -> np.ndarray:
    """Rows ``start .. stop`` of a :class:`RowFile`, a :class:`StackStore` (texel rows,
    ``(b, n, 3)``) or an array in memory (a view, not a copy)."""
    if isinstance(source, RowFile):
        return source.read(start, stop)
    if isinstance(source, (StackStore, ArrayStack)):
        return source.rows(start, stop)
    return source[start:stop]


def length(source) -> int:
    """Rows of :func:`rows_of`'s ``source``."""
    return source.texels if isinstance(source, (StackStore, ArrayStack)) else len(source)
