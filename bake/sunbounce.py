"""Compression of the sun-bounce stacks (docs/sun.md, item 5): one image per light the sun
can be in, each its column as it is (no base, no gain), encoded and checked as the client
decodes it; a light's refinement image is kept only where its coarse image alone would show
as displayed (the judge: bake.sundisplay). Neighbouring patches may share one image, their
solid-angle mean (:class:`SharedImages`; docs/sun.md, "Shared images"), and what that costs
each patch as displayed is recorded (:func:`shared_errors`).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bake.basisu import encode
from bake.compact_reader import CompactReader
from bake.compress import CompactStack
from bake.ktx2decoder import decode
from bake.quantize import float32_list, quantized_png, refinement_png
from bake.rowstore import as_stack
from bake.sundisplay import SUN_BOUNCE_DECODE_CHUNK, DisplayCheck, DisplaySkies

# Of the budget as displayed, the share a patch's sharing of its group's image may take
# before encoding (groups_within); the image's encoding error, judged against the group's
# column, takes the rest (errors of both kinds add about in quadrature: 0.7^2 + 0.7^2 ~ 1).
SHARING_SHARE = 0.7


@dataclass
class SharedImages:
    """Which sun-path lights share one sun-bounce image: ``groups`` {representative light:
    its members, sorted, the representative first}. A group is the sun-path patches whose
    centroids lie in one patch of a coarser dome (:meth:`of_dome`); its
    image is its members' columns summed and scaled to the representative's solid angle,
    ``omega_rep / sum(omega_q) * sum_q B_q``, so that with the sun in any member ``p`` the
    client's ``E_sun / omega_p * column_p`` (``column_p``: the shared image scaled by
    ``omega_p / omega_rep``) is ``E_sun * sum_q B_q / sum_q omega_q``: the sun's bounce
    averaged over the group's patches; each member then scales it by its own least-squares
    gain per channel (:func:`fit_member_gains`)."""

    groups: dict[int, list[int]]
    solid_angles_sr: np.ndarray  # (n,) the dome's
    kind: str
    frequency: int  # the coarser dome's

    @classmethod
    def of_dome(cls, kind: str, frequency: int, lights, max_lights: int | None
                ) -> SharedImages | None:
        """The groups of ``lights`` (the sun-path patches) of a ``kind`` dome of this
        ``frequency`` by the patches of the dome of about ``max_lights`` lights
        (:meth:`bake.dome.Dome.for_light_count`), or None when the build's dome has no more
        lights than that (or ``max_lights`` is None): the sun's bounce is kept at no finer an
        angular step than that dome's."""
        from bake.dome import Dome
        from daylit.spherical import PatchLookup

        fine = Dome.build(kind, frequency)
        if not max_lights or fine.count <= max_lights:
            return None
        rough = Dome.for_light_count(max_lights)
        if rough.count >= fine.count:
            return None
        owner = PatchLookup(rough.vertices)(fine.centroids)
        by_patch: dict[int, list[int]] = {}
        for p in sorted(int(i) for i in lights):
            key = int(owner[p]) if owner[p] >= 0 else -1 - p  # outside every coarse patch: alone
            by_patch.setdefault(key, []).append(p)
        groups = {members[0]: members for members in by_patch.values()}
        return cls(groups, fine.solid_angles_sr, rough.kind, rough.frequency)

    @property
    def representatives(self) -> list[int]:
        return sorted(self.groups)

    def image_of(self, n: int) -> list:
        """(n,) the light whose files hold each light's image; None for lights without."""
        out: list = [None] * n
        for rep, members in self.groups.items():
            for q in members:
                out[q] = rep
        return out

    def ratio(self, light: int, rep: int) -> float:
        """``omega_light / omega_rep``: a member's scale and offset over its image's."""
        return float(self.solid_angles_sr[light] / self.solid_angles_sr[rep])


class SharedColumns:
    """A sun-bounce stack (a :mod:`bake.rowstore` stack) read as :class:`SharedImages` store
    it: a representative's column is its group's, ``omega_rep / sum(omega_q) * sum_q B_q``;
    any other light's its own."""

    def __init__(self, image, shared: SharedImages):
        self.image = as_stack(image)
        self.shared = shared
        self.shape = self.image.shape
        self.valid = self.image.valid
        self.work = getattr(self.image, "work", None)

    def columns(self, lights) -> np.ndarray:
        out = []
        omega = self.shared.solid_angles_sr
        for p in lights:
            members = self.shared.groups.get(int(p), [int(p)])
            total = np.zeros(self.shape[:2] + (3,), dtype=np.float64)
            for column in self.image.columns(members):
                total += column
            out.append((total * (omega[p] / omega[members].sum())).astype(np.float32))
        return np.stack(out)

    def column(self, light: int) -> np.ndarray:
        return self.columns([light])[0]


def share_entry(entry: dict, shared: SharedImages, n: int) -> dict:
    """A sun-bounce entry whose ``lights`` hold the representatives' images, extended to
    every member: ``scale``/``offset`` the representative's times ``omega_p / omega_rep``,
    ``image[p]`` the representative (whose files hold the image), and ``shared``: the
    coarser dome and how many images."""
    table = entry["lights"]
    for rep, members in shared.groups.items():
        for q in members:
            if q == rep:
                continue
            f = shared.ratio(q, rep)
            table["scale"][q] = [float32_list(np.asarray(level) * f)
                                 for level in table["scale"][rep]]
            table["offset"][q] = [float32_list(np.asarray(level) * f)
                                  for level in table["offset"][rep]]
    table["image"] = shared.image_of(n)
    entry["shared"] = {"kind": shared.kind, "frequency": shared.frequency,
                       "images": len(shared.groups),
                       "lights": sum(len(m) for m in shared.groups.values())}
    return entry


def compress_sun_bounce(image, name, out_dir, lights, settings, sky=None,
                        skies: DisplaySkies | None = None,
                        shared: SharedImages | None = None) -> CompactStack | None:
    """Compress a sun-bounce stack ``image`` (H, W, n, 3), whose columns outside ``lights``
    (the patches the sun can be in) are zero, into one image per light of ``lights``: its
    column, as it is (no base, no gain, no ``d - I``).

    The sun's bounce is one column at a time (the sun's patch ``p``: ``E_sun /
    solid_angle_p`` times column ``p``), so a client fetches that column's image alone, on
    demand, as it fetches a selected light's own image of an ordinary stack; a low-rank base
    would have to be downloaded whole, and the columns are not low rank anyway (docs/sun.md,
    item 5).

    Each image is encoded as the ordinary stacks' light images
    (:func:`bake.compress.compress_stack`): quantized to 8 bits with its own scale and
    offset, encoded at UASTC level ``settings.uastc_level`` and decoded. Where the coarse
    image alone is off by more than ``settings.sun_bounce_budget`` as displayed
    (:class:`DisplayCheck`: ``sky`` (H, W, n, 3), the same atlas's or view's sky stack,
    relit with ``skies``' clear sky for that patch, plus the sun's direct term estimated
    from the sky stack's and ``image``'s column, plus the bounce) it is encoded again at
    level ``settings.sun_bounce_level``, and where that is still off, what was lost is
    encoded as a refinement at level ``settings.refine_level``; without ``sky`` and
    ``skies``, or with the budget None, every light keeps its refinement. Every column is
    then decoded as the client decodes it (:class:`CompactReader`) and checked against the
    master: RMS error over the stack's valid texels relative to the column's mean there, and
    as displayed.

    With ``shared`` (:class:`SharedImages`) the lights of a group share one image, their
    group's (:class:`SharedColumns`): only the representatives are encoded and judged (each
    against its group's column, under its own display sky), and the entry lists every
    member (:func:`share_entry`), each with its own gain per channel against its own column
    (:func:`fit_member_gains`).

    Writes ``ktx2/<name>.L<i>.ktx2`` for each light ``i`` of ``lights`` and
    ``ktx2/<name>.L<i>r.ktx2`` for those that keep a refinement. Returns the
    :class:`CompactStack` (entry ``{"k": 0, "lights", "error"}``: ``lights.ktx2`` one pattern
    per level any light has, ``scale[i]`` / ``offset[i]`` one entry per level light ``i`` has;
    ``error`` holds ``max`` and ``median`` over the columns, the ``worst_light``, the number
    of ``test_lights``, and when judged ``displayed``: ``max``, ``median``, ``worst_light``,
    ``budget`` and ``refined`` lights), or ``None`` when the stack is zero everywhere."""
    started = time.perf_counter()
    image = as_stack(image)
    H, W, n, _ = image.shape
    lights = np.asarray(lights, dtype=int)
    valid = image.valid
    if not valid.any() or len(lights) == 0:
        return None
    own = image  # each patch's own column: the direct term's estimate (DisplayCheck)
    budget = settings.sun_bounce_budget
    # One judge, one pass over the sky stack: with shared images it holds every drawn light,
    # the groups checked with it, the representatives' images judged with it and then every
    # member's error against its own column (shared_errors).
    judged = lights
    if shared is not None:
        drawn = set(lights.tolist())
        shared = SharedImages({rep: [q for q in members if q in drawn]
                               for rep, members in shared.groups.items() if rep in drawn},
                              shared.solid_angles_sr, shared.kind, shared.frequency)
        judged = sorted(drawn)
    check = (DisplayCheck(sky, skies, judged, bounce=own)
             if sky is not None and skies is not None else None)
    split_out = 0
    if shared is not None:
        if (check is not None and budget is not None
                and settings.sun_bounce_sharing == "within_budget"):
            grouped = len(shared.groups)
            shared = groups_within(shared, own, check, SHARING_SHARE * budget)
            split_out = len(shared.groups) - grouped
        image = SharedColumns(image, shared)
        lights = np.asarray(shared.representatives, dtype=int)
    try:
        result = _compress_columns(image, name, out_dir, lights, settings, check, budget,
                                   started)
        if result is not None and shared is not None:
            share_entry(result.entry, shared, n)
            result.entry["shared"]["split_out"] = split_out
            fit_member_gains(out_dir, result.entry, own, judged)
            if check is not None:
                result.entry["error"]["displayed"]["shared"] = shared_errors(
                    out_dir, result.entry, own, check, budget)
        return result
    finally:
        if check is not None:
            check.remove()


def groups_within(shared: SharedImages, own, check: DisplayCheck, limit: float
                  ) -> SharedImages:
    """``shared`` with the patches that sharing would put over ``limit`` as displayed taken
    out of their groups, each to an image of its own: in each group, the group's column
    (the members' solid-angle mean) times each member's least-squares gain
    (:func:`least_squares_gain`, as :func:`fit_member_gains` will give it) is judged against
    the member's own column of ``own`` (H, W, n, 3) by ``check`` (made with ``bounce=own``,
    holding every member); while the worst member is over ``limit``, it leaves the group
    and the rest's mean is judged again. Before encoding: ``limit`` is the share of the
    budget left to sharing (:data:`SHARING_SHARE`), the rest to the image's encoding."""
    own = as_stack(own)
    valid = own.valid
    omega = shared.solid_angles_sr
    # Whole groups, about SUN_BOUNCE_DECODE_CHUNK lights at a time: a stack on disk reads
    # every row of a block of lights for each call (bake.rowstore.StackStore.columns).
    batches: list[list[list[int]]] = [[]]
    for members in shared.groups.values():
        if batches[-1] and sum(map(len, batches[-1])) + len(members) > SUN_BOUNCE_DECODE_CHUNK:
            batches.append([])
        batches[-1].append(list(members))
    groups: dict[int, list[int]] = {}
    for batch in batches:
        lights = [p for members in batch for p in members]
        columns = dict(zip(lights, own.columns(lights), strict=True))
        shown = dict(zip(lights, check.sky_shown(lights), strict=True))
        for members in batch:
            while len(members) > 1:
                total = (sum(columns[q].astype(np.float64) for q in members)
                         / omega[members].sum())
                errors = []
                for p in members:
                    mean = total * omega[p]
                    gain = least_squares_gain(mean[valid], columns[p][valid])
                    errors.append(check.error(p, shown[p], columns[p], mean * gain))
                worst = int(np.argmax(errors))
                if errors[worst] <= limit:
                    break
                alone = members.pop(worst)
                groups[alone] = [alone]
            groups[members[0]] = members
    return SharedImages(dict(sorted(groups.items())), omega, shared.kind, shared.frequency)


def fit_member_gains(out_dir: Path, entry: dict, own, lights) -> None:
    """Give each light ``p`` of ``lights`` that reads a shared image (``entry`` after
    :func:`share_entry`) its own gain per channel: the least-squares one, over the valid
    texels of ``own`` (H, W, n, 3, each patch's own column), of its decoded image against its
    own master column, ``g_c = sum(decoded_c * own_c) / sum(decoded_c ** 2)``; its ``scale``
    and ``offset`` (every level) are multiplied by it, so the client draws ``g`` times the
    group's image with no change of its own.

    The group's image is the members' mean; part of how a member's own bounce differs from it
    is strength (the sun's cosine on the surfaces that throw it off changes across a group, up
    to twice from the lowest row of patches to the next), which the gain restores; the rest is
    pattern, which :func:`groups_within` judges.
    As displayed, the relit sky and the direct term do not depend on the gain, so the
    least-squares gain is the one with the smallest error the judge can see for that image
    (docs/sun.md, "Shared images"). Records ``entry["shared"]["gains"]``: the smallest and
    largest gain over lights and channels."""
    own = as_stack(own)
    valid = own.valid
    table = entry["lights"]
    reader = CompactReader(out_dir, entry, own.shape[:2])
    lowest, highest = np.inf, -np.inf
    for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
        chunk = [int(i) for i in lights[start : start + SUN_BOUNCE_DECODE_CHUNK]]
        decoded = reader.lights(chunk)
        for p, column in zip(chunk, own.columns(chunk), strict=True):
            gain = least_squares_gain(decoded[p][valid], column[valid])
            table["scale"][p] = [float32_list(np.asarray(level) * gain)
                                 for level in table["scale"][p]]
            table["offset"][p] = [float32_list(np.asarray(level) * gain)
                                  for level in table["offset"][p]]
            lowest, highest = min(lowest, gain.min()), max(highest, gain.max())
        reader.forget_lights()
    entry["shared"]["gains"] = [round(float(lowest), 4), round(float(highest), 4)]


def least_squares_gain(decoded: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(3,) per channel, the gain ``g >= 0`` that minimizes ``sum (g * decoded - truth)^2``
    over texels (``decoded``, ``truth``: (T, 3)); 1 for a channel whose decoded image is
    zero."""
    decoded = decoded.astype(np.float64)
    power = (decoded**2).sum(axis=0)
    fit = (decoded * truth.astype(np.float64)).sum(axis=0)
    return np.where(power > 0.0, np.clip(fit / np.where(power > 0.0, power, 1.0), 0.0, None),
                    1.0)


def shared_errors(out_dir: Path, entry: dict, own, check: DisplayCheck,
                  budget: float | None) -> dict:
    """What sharing costs a visitor: each sun-path light ``p`` of ``check.lights`` decoded as
    the client decodes it (its group's image with its own scale, ``entry`` after
    :func:`share_entry`) against its *own* master column of ``own`` (H, W, n, 3), as
    displayed under its own display sky with the sun's direct term (``check``, made with
    ``bounce=own``). The images are judged against their group's column
    (:func:`compress_sun_bounce`), so this is the error the budget does not see (docs/sun.md,
    "Shared images"). Returns ``{"max", "median", "worst_light", "lights", "over_budget"}``
    (the last with a budget)."""
    own = as_stack(own)
    lights = check.lights
    reader = CompactReader(out_dir, entry, own.shape[:2])
    _, displayed = sun_bounce_errors(reader, own, own.valid, lights, check)
    out = {"max": round(float(displayed.max()), 6),
           "median": round(float(np.median(displayed)), 6),
           "worst_light": int(lights[int(np.argmax(displayed))]),
           "lights": len(lights)}
    if budget is not None:
        out["over_budget"] = int((displayed > budget).sum())
    return out


def _compress_columns(image, name, out_dir, lights, settings, check, budget, started):
    """:func:`compress_sun_bounce` once its stack (a :mod:`bake.rowstore` stack) and its
    check are ready; its columns read a chunk of lights at a time."""
    H, W, n, _ = image.shape
    valid = image.valid
    judged = check is not None and budget is not None
    # The selected lights' images' two levels (coarse at uastc_level, refinement at
    # refine_level), not the RMS stacks' cheaper refinement (rms_refine_level): a column's
    # refinement is noise-like, and level 1 cut the worst column's error for a few per cent
    # more bytes (docs/benchmarks.md, "Figures behind choices in the code").
    image_settings = settings
    (out_dir / "ktx2").mkdir(exist_ok=True)
    light_files = []
    refined: list[int] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        coarse_dir, refine_dir = tmp / "coarse", tmp / "refine"
        coarse_dir.mkdir()
        refine_dir.mkdir()
        coarse_q = {}
        for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
            chunk = [int(i) for i in lights[start : start + SUN_BOUNCE_DECODE_CHUNK]]
            for i, column in zip(chunk, image.columns(chunk), strict=True):
                coarse_q[i] = quantized_png(column, tmp / f"{name}.L{i:04d}.png")
        # The coarse image: UASTC at uastc_level, or a smaller encoding where one is within
        # the budget as displayed (_cheaper_within); the lights still over the budget are
        # encoded again at each later level of the ladder (the same 8-bit image: the same
        # scale and offset), and those over it after the last are refined against it
        # (docs/compact-assets.md, "The sun's bounce"). Not judged: the first level alone,
        # every light refined.
        ladder = coarse_levels(settings) if judged else coarse_levels(settings)[:1]
        first_settings, first_level = ladder[0]
        encode([q.path for q in coarse_q.values()], coarse_dir, first_settings, array=False,
               level=first_level)
        cheaper = _cheaper_within(lights, coarse_dir, name, coarse_q, image, check, budget,
                                  settings, tmp) if judged else {}
        refine_q = {}
        over = [int(i) for i in lights if int(i) not in cheaper]
        for step, (step_settings, level) in enumerate(ladder):
            if step:
                step_dir = tmp / f"coarse{step}"
                step_dir.mkdir()
                encode([coarse_q[i].path for i in over], step_dir, step_settings,
                       array=False, level=level)
                for i in over:
                    shutil.move(step_dir / f"{name}.L{i:04d}.ktx2",
                                coarse_dir / f"{name}.L{i:04d}.ktx2")
            last = step == len(ladder) - 1
            over = _shown_coarse(over, coarse_dir, name, coarse_q, image,
                                 check if judged else None, budget,
                                 refine_q if last else None, tmp)
            if not over:
                break
        refined.extend(over)
        if refine_q:
            encode(
                [q.path for q in refine_q.values()], refine_dir, image_settings, array=False,
                level=image_settings.refine_level,
            )
        for i in lights:
            for folder, suffix in ((coarse_dir, ""), (refine_dir, "r")):
                if suffix and int(i) not in refine_q:
                    continue
                target = out_dir / "ktx2" / f"{name}.L{i:04d}{suffix}.ktx2"
                shutil.move(folder / f"{name}.L{i:04d}{suffix}.ktx2", target)
                light_files.append(target)
    encode_s = time.perf_counter() - started
    # [light][level], null for the lights the sun is never in (they have no images); a
    # light without a refinement has one level.
    scales: list = [None] * n
    offsets: list = [None] * n
    for i, q in coarse_q.items():
        levels = [q] + ([refine_q[i]] if i in refine_q else [])
        scales[i] = [level.scale_list for level in levels]
        offsets[i] = [level.offset_list for level in levels]
    patterns = [f"ktx2/{name}.L{{index:04d}}.ktx2"]
    if refine_q:
        patterns.append(f"ktx2/{name}.L{{index:04d}}r.ktx2")
    entry = {"k": 0, "lights": {"ktx2": patterns, "scale": scales, "offset": offsets}}
    reader = CompactReader(out_dir, entry, (H, W))
    errors, displayed = sun_bounce_errors(reader, image, valid, lights, check)
    entry["error"] = {
        "test_lights": int(len(lights)),
        "max": round(float(errors.max()), 6),
        "median": round(float(np.median(errors)), 6),
        "worst_light": int(lights[int(np.argmax(errors))]),
    }
    if check is not None:
        entry["error"]["displayed"] = {
            "max": round(float(displayed.max()), 6),
            "median": round(float(np.median(displayed)), 6),
            "worst_light": int(lights[int(np.argmax(displayed))]),
            "budget": budget,
            "refined": len(refined),
            "cheaper": {label: sum(v == label for v in cheaper.values())
                        for label, *_ in cheaper_encodings(settings)},
        }
    compact = CompactStack(entry, light_files, encode_s=encode_s)
    compact.light_bytes = sum(p.stat().st_size for p in light_files)
    return compact


def coarse_levels(settings) -> list[tuple]:
    """The coarse encodings a sun-bounce image goes through while it is over the budget as
    displayed, as ``(settings, UASTC level)`` for :func:`bake.basisu.encode`: UASTC at
    ``settings.uastc_level``, then at ``settings.sun_bounce_level`` when that differs (a
    build whose ``encoding`` is ``"etc1s"``: ETC1S alone)."""
    if settings.encoding == "etc1s":
        return [(settings, None)]
    ladder = [(settings, settings.uastc_level)]
    if settings.sun_bounce_level != settings.uastc_level:
        ladder.append((settings, settings.sun_bounce_level))
    return ladder


def cheaper_encodings(settings) -> list[tuple]:
    """The encodings a judged sun-bounce image tries before plain UASTC at
    ``settings.uastc_level``, in turn, as ``(label, settings, UASTC level, RDO lambda)`` for
    :func:`bake.basisu.encode`: with ``settings.sun_bounce_encoding`` ``"smallest"``, ETC1S
    (quality 255), then UASTC at that level with each of ``settings.sun_bounce_rdo_lambdas``;
    none for ``"uastc"`` or a build whose ``encoding`` is ``"etc1s"``."""
    if settings.sun_bounce_encoding != "smallest" or settings.encoding == "etc1s":
        return []
    out = [("etc1s", replace(settings, encoding="etc1s"), None, None)]
    for lam in settings.sun_bounce_rdo_lambdas:
        out.append((f"uastc rdo {lam:g}", settings, settings.uastc_level, lam))
    return out


def _cheaper_within(lights, coarse_dir: Path, name: str, coarse_q: dict, image, check,
                    budget, settings, tmp: Path) -> dict[int, str]:
    """The ``lights`` that keep a cheaper encoding than their plain UASTC image in
    ``coarse_dir``: for each of :func:`cheaper_encodings` in turn, the lights not yet kept
    whose image so encoded is smaller than the plain one and within ``budget`` as displayed
    (``check``); its file replaces the plain one there. Returns ``{light: label}``.

    ETC1S is 4-6 times smaller than UASTC on the models' faces and the views, UASTC with
    RDO about a third smaller; once the judge counts the sun's direct term they are within
    the budget for part of the lights. On smooth closed-form stacks (the hull planes' ``d``)
    plain UASTC's Zstandard-packed blocks are the smallest (docs/benchmarks.md, "The
    sun-bounce images in their smallest encoding within the budget")."""
    file = f"{name}.L{{:04d}}.ktx2".format
    left = [int(i) for i in lights]
    kept: dict[int, str] = {}
    for step, (label, step_settings, level, rdo) in enumerate(cheaper_encodings(settings)):
        if not left:
            break
        step_dir = tmp / f"cheaper{step}"
        step_dir.mkdir()
        encode([coarse_q[i].path for i in left], step_dir, step_settings, array=False,
               level=level, rdo_lambda=rdo)
        smaller = [i for i in left
                   if (step_dir / file(i)).stat().st_size < (coarse_dir / file(i)).stat().st_size]
        over = set(_shown_coarse(smaller, step_dir, name, coarse_q, image, check, budget,
                                 None, tmp))
        for i in smaller:
            if i not in over:
                shutil.move(step_dir / file(i), coarse_dir / file(i))
                kept[i] = label
        left = [i for i in left if i not in kept]
    return kept


def _shown_coarse(lights, folder: Path, name: str, coarse_q: dict, image, check, budget,
                  refine_q: dict | None, tmp: Path) -> list[int]:
    """The ``lights`` whose coarse image in ``folder`` is off by more than ``budget`` as
    displayed (``check``: a :class:`DisplayCheck`; None: every light), the masters read from
    ``image`` (a :mod:`bake.rowstore` stack). With ``refine_q``, the
    refinement image of each of them (what its coarse image lost) is written into ``tmp`` and
    listed there, as its chunk is decoded (not every decoded image held at once: memory)."""
    over = []
    for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
        chunk = [int(i) for i in lights[start : start + SUN_BOUNCE_DECODE_CHUNK]]
        decoded = decode([folder / f"{name}.L{i:04d}.ktx2" for i in chunk])
        shown = check.sky_shown(chunk) if check is not None else None
        columns = image.columns(chunk)
        for j, i in enumerate(chunk):
            coarse = coarse_q[i].value(decoded[j][0])
            # The coarse image alone is enough where its error does not show.
            if check is not None and check.error(i, shown[j], columns[j], coarse) <= budget:
                continue
            over.append(i)
            if refine_q is not None:
                refine_q[i] = refinement_png(
                    columns[j] - coarse, tmp / f"{name}.L{i:04d}r.png", None
                )
        del decoded, shown, columns
    return over


def sun_bounce_errors(reader: CompactReader, image, valid, lights,
                      check: DisplayCheck | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each column ``p`` of ``lights`` decoded from its images as the client decodes it,
    against the master ``image[:, :, p]`` (H, W, n, 3): RMS error over the ``valid`` texels
    (H, W) relative to the column's mean there, and (with ``check``) as displayed
    (:meth:`DisplayCheck.error`; empty without). Returns two arrays (len(lights),)."""
    image = as_stack(image)
    errors, displayed = [], []
    for start in range(0, len(lights), SUN_BOUNCE_DECODE_CHUNK):
        chunk = [int(i) for i in lights[start : start + SUN_BOUNCE_DECODE_CHUNK]]
        decoded = reader.lights(chunk)
        shown = check.sky_shown(chunk) if check is not None else None
        columns = image.columns(chunk)
        for j, i in enumerate(chunk):
            truth = columns[j][valid].astype(np.float64)
            rms = np.sqrt(((decoded[i][valid] - truth) ** 2).mean())
            errors.append(rms / max(float(truth.mean()), 1e-30))
            if check is not None:
                displayed.append(check.error(i, shown[j], columns[j], decoded[i]))
        reader.forget_lights()
    return np.array(errors), np.array(displayed)
