"""Occlusion by visitors (issue 6): milliseconds per site-camera frame, and accuracy.

For 640x480 and 1024x512 frames of the standard synthetic sequence
(server/occlusion/synthetic.py ``default_site``: 12 s at 10 frames/s, four people at 7-26 m
with cast shadows, one standing still for 6 s, daylight dimming and warming), on one core:

- *ours*: :class:`server.occlusion.OcclusionProcessor` with its default settings (graph cut in
  regions of interest and a band around possible person pixels, table look-ups);
- *full-frame cut*: the same energy and code with ``full_frame=True``, one graph node per pixel
  (the plain method, as in the paper), over the first 30 frames after learning;
- *MOG2*: OpenCV's ``createBackgroundSubtractorMOG2`` (with its own shadow detection), a
  well-known fast background subtractor, for speed and accuracy reference.

The three run interleaved frame by frame, so machine load hits them alike; each time is the
wall time of one ``process``/``apply`` call. Accuracy is against the exact ground truth over
every frame after learning: person IoU, share of cast-shadow pixels removed and of person
pixels kept, foot-line depth error of people whose feet are in view (ours only), and
in-front/behind decisions against the virtual building's depth image. The paper (Kakuta et
al. Sec. 3.3) reports 897.4 ms/frame at 1024x512 on a Core2Duo E6850.

With ``--ablation`` it also prints what each part of the method is worth: the accuracy on the
480x270 sequence with one setting changed at a time (the paper's shadow test alone, the global
background mixture switched on, no temporal or spatial prior).

With ``--synthetic`` it measures ours on the standard sequence as drawn now (a broadband
camera under daylight spectra, server/occlusion/spectralcamera.py) beside the same sequence
drawn with the detector's own narrow-band Wien model (``light_model="narrowband"``, the
sequence before 2026-11-25), each raw, through JPEG 75 and through H.264 (libx264 crf 28), at
480x270 and 1024x512, with 1.6 s of empty site: issue 18's figures (person IoU median over
frames with people, shadow kept, phantom regions in the empty frames after learning) and the
time to draw a frame (the demo's and the replays' cost) and to process it.

With ``--codecs`` it runs the broadband sequence raw, through JPEG 75 and through H.264 at
480x270 and 1024x512 with the detector after issue 18's codec work but before the outline
work (those parts switched off by settings, :data:`BEFORE_OUTLINES` and
:data:`BEFORE_STANDING`), after the outline work but before the standing-height and
shadow-deviation limits (:data:`BEFORE_STANDING`) and as it is now, frame by frame on the
same frames.

With ``--baseline REV`` (``--codecs`` or ``--heldout``) the detector of git revision REV of
this repository (its ``server`` package extracted by ``git archive`` under another name) runs
beside this one, interleaved frame by frame on the same frames, each first in turn: the
same-run baseline of the time per frame (with ``--codecs`` in place of the settings variants).

With ``--refit`` it times only the person colour mixture's warm refit, this code's numpy EM
against OpenCV's ``EM.trainM`` from the same posteriors (the frames that set the p95 before
2026-11-25).

With ``--heldout`` it measures ours and MOG2 (with a 3x3 open and a 5x5 close) on the held-out
sequences of tests/server/occlusion/heldout.py (a broadband camera, neutral or bluish shadows
with penumbra, noise, a passing cloud, JPEG 75, a video codec, +-0.5 px camera shake; a
generator that is not the detector's model), 1024x512, one condition at a time: person IoU
(median over frames with people), share of the cast-shadow area kept as person, phantom
regions (connected person regions of at least 25 px) in the empty frames after learning, and
ms per frame (median, p95).

Run: ``.venv/bin/python benchmarks/bench_occlusion.py [--ablation] [--refit] [--synthetic]
[--codecs] [--heldout [CONDITION ...]] [--baseline REV]``
(about a minute, two with the ablation; the held-out conditions about 15 minutes; ``--help``
lists the conditions).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import functools  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from server.occlusion import OcclusionProcessor, OcclusionSettings  # noqa: E402
from server.occlusion.synthetic import VIRTUAL_BOX, box_depth_image, default_site  # noqa: E402
from tests.server.occlusion.conftest import (  # noqa: E402
    feet_visible,
    isolated,
    match_people,
    run_sequence,
)

cv2.setNumThreads(1)
SIZES = [(640, 480), (1024, 512)]
FULL_FRAME_FRAMES = 30
PAPER_MS = 897.4


class Tally:
    """Accuracy of one method against the ground truth."""

    def __init__(self):
        self.inter = self.union = self.truth = 0
        self.shadow = self.shadow_removed = 0
        self.depth_err: list[float] = []
        self.decisions = self.decisions_right = 0
        self.ms: list[float] = []

    def add(self, person: np.ndarray, truth) -> None:
        gt = truth.person
        self.inter += np.count_nonzero(person & gt)
        self.union += np.count_nonzero(person | gt)
        self.truth += np.count_nonzero(gt)
        self.shadow += np.count_nonzero(truth.shadow)
        self.shadow_removed += np.count_nonzero(truth.shadow & ~person)

    def row(self) -> str:
        iou = self.inter / max(self.union, 1)
        kept = self.inter / max(self.truth, 1)
        removed = self.shadow_removed / max(self.shadow, 1)
        depth = f"{100 * max(self.depth_err):.1f} %" if self.depth_err else "-"
        dec = (f"{self.decisions_right}/{self.decisions}" if self.decisions else "-")
        return f"{iou:.3f} | {removed:.3f} | {kept:.3f} | {depth} | {dec}"


def timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, 1e3 * (time.perf_counter() - t0)


def cpu_timed(fn, *args):
    """``(result, wall ms, CPU ms of this process)``: on a shared machine the CPU time is the
    one-core cost (OpenCV and BLAS run one thread here), the wall time what it took."""
    c0, t0 = time.process_time(), time.perf_counter()
    out = fn(*args)
    return out, 1e3 * (time.perf_counter() - t0), 1e3 * (time.process_time() - c0)


def run(width: int, height: int) -> None:
    site = default_site(width, height)
    virtual = box_depth_image(site.camera, *VIRTUAL_BOX)
    ours = OcclusionProcessor(site.camera, virtual)
    full = OcclusionProcessor(site.camera, virtual, OcclusionSettings(full_frame=True))
    mog2 = cv2.createBackgroundSubtractorMOG2(history=200, varThreshold=16, detectShadows=True)
    tallies = {"ours": Tally(), "full": Tally(), "mog2": Tally()}
    stages: dict[str, list[float]] = {}
    learn = ours.settings.learn_frames
    for i in range(site.frame_count):
        truth = site.frame(i)
        frame = truth.image
        r, ms = timed(ours.process, frame)
        if i < learn + FULL_FRAME_FRAMES:
            rf, ms_full = timed(full.process, frame)
        fg, ms_mog = timed(mog2.apply, frame)
        if r.learning:
            continue
        tallies["ours"].ms.append(ms)
        tallies["mog2"].ms.append(ms_mog)
        for k, v in r.timings_ms.items():
            stages.setdefault(k, []).append(v)
        tallies["ours"].add(r.person_mask > 0, truth)
        tallies["mog2"].add(fg == 255, truth)  # MOG2 marks shadows 127
        if i < learn + FULL_FRAME_FRAMES:
            tallies["full"].ms.append(ms_full)
            tallies["full"].add(rf.person_mask > 0, truth)
        for p, tp in match_people(r, truth, width, height):
            tallies["ours"].depth_err.append(abs(p.depth_m / tp.depth_m - 1.0))
        ideal = truth.in_front(virtual)
        for tp in truth.people:
            over = (truth.person_index == tp.index) & np.isfinite(virtual)
            if np.count_nonzero(over) < 30 or not (feet_visible(truth, tp) and isolated(truth,
                                                                                         tp)):
                continue
            in_front = np.count_nonzero(ideal & over) > np.count_nonzero(over) // 2
            shown = np.count_nonzero((r.mask > 0) & over) / np.count_nonzero(over)
            tallies["ours"].decisions += 1
            tallies["ours"].decisions_right += (shown >= 0.9) if in_front else (shown <= 0.02)

    med = {k: statistics.median(t.ms) for k, t in tallies.items()}
    p95 = {k: float(np.percentile(t.ms, 95)) for k, t in tallies.items()}
    print(f"\n{width}x{height}: {len(tallies['ours'].ms)} frames after learning "
          f"({len(tallies['full'].ms)} for the full-frame cut); load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores\n")
    print("| method | median ms | p95 ms | full-frame cut / method | person IoU | shadow "
          "removed | person kept | depth max error | in front / behind right |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    names = {"ours": "ours (regions + band)", "full": "full-frame cut (same energy)",
             "mog2": "OpenCV MOG2"}
    for k in ("ours", "full", "mog2"):
        print(f"| {names[k]} | {med[k]:.1f} | {p95[k]:.1f} | {med['full'] / med[k]:.1f}x | "
              f"{tallies[k].row()} |")
    print(f"\npaper (Core2Duo E6850, 1024x512): {PAPER_MS} ms; ours is "
          f"{PAPER_MS / med['ours']:.0f}x fewer ms per frame than the paper's (other hardware)")
    print("stages of ours, median ms: " + ", ".join(
        f"{k} {statistics.median(v):.2f}" for k, v in stages.items() if k != "total"))


ABLATION = [
    ("defaults", {}),
    ("paper's shadow test alone (conditions 1-2)", {"shadow_signature": False,
                                                   "shadow_min_blue_shift": 0.0}),
    ("+ minimum blue shift, no signature", {"shadow_signature": False}),
    ("global background mixture, weight 0.001", {"bg_global_weight": 0.001}),
    ("global background mixture, weight 0.01", {"bg_global_weight": 0.01}),
    ("global background mixture, weight 0.05", {"bg_global_weight": 0.05}),
    ("no temporal prior (alpha = 0)", {"temporal_weight": 0.0}),
    ("no spatial prior (beta = 0)", {"spatial_weight": 0.0}),
]


def ablation() -> None:
    site = default_site(480, 270)
    virtual = box_depth_image(site.camera, *VIRTUAL_BOX)
    print("\nAblation, 480x270 standard sequence, every frame after learning:\n")
    print("| variant | person IoU | worst frame IoU | shadow removed | person kept | standing "
          "person, worst IoU | in front / behind right |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, changes in ABLATION:
        _, st = run_sequence(site, virtual, OcclusionSettings(**changes))
        right = sum((shown >= 0.9) if front else (shown <= 0.02)
                    for _, _, front, shown in st.decisions)
        print(f"| {name} | {st.person_iou:.3f} | {min(st.frame_iou):.3f} | "
              f"{st.shadow_removed_fraction:.3f} | {st.person_kept:.3f} | "
              f"{min(i for _, i in st.standing_iou):.3f} | {right}/{len(st.decisions)} |")


def baseline_processor(rev: str):
    """The ``OcclusionProcessor`` class of git revision ``rev`` of this repository, for a
    same-run baseline: its ``server`` package extracted (``git archive``) into a temporary
    folder under another package name, its own imports of ``server.`` renamed to match."""
    import importlib
    import subprocess
    import tempfile

    root = Path(__file__).resolve().parents[1]
    sha = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", rev], check=True,
                         capture_output=True, text=True).stdout.strip()
    name = f"baseline_{sha}"
    folder = Path(tempfile.mkdtemp(prefix="daylit-bench-"))
    archive = subprocess.run(["git", "-C", str(root), "archive", rev, "server"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    (folder / "server").rename(folder / name)
    for py in (folder / name).rglob("*.py"):
        text = py.read_text("utf-8")
        py.write_text(text.replace("from server.", f"from {name}.")
                      .replace("import server.", f"import {name}."), "utf-8")
    sys.path.insert(0, str(folder))
    return importlib.import_module(f"{name}.occlusion").OcclusionProcessor, sha


def mog2_open_close(mog2, frame: np.ndarray) -> np.ndarray:
    """MOG2's foreground (shadows, marked 127, left out) after a 3x3 open and a 5x5 close."""
    fg = (mog2.apply(frame) == 255).astype(np.uint8)
    fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    return cv2.morphologyEx(fg, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) > 0


def regions(mask: np.ndarray, min_px: int = 25) -> int:
    """Connected regions (8-neighbours) of at least ``min_px`` pixels."""
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return int(np.count_nonzero(stats[1:, cv2.CC_STAT_AREA] >= min_px))


def heldout(names: list[str] | None = None, width: int = 1024, height: int = 512,
            duration_s: float = 6.0, baseline: str | None = None) -> None:
    from tests.server.occlusion.heldout import CONDITIONS, HeldoutSequence

    before, sha = baseline_processor(baseline) if baseline else (None, None)

    print(f"\nHeld-out sequences, {width}x{height}, {duration_s:.0f} s at 10 frames/s "
          f"(10 learned, 6 empty, then three walkers at 8, 14 and 22 m)\n")
    print("| condition | method | person IoU (median) | worst frame IoU | shadow kept | "
          "phantom regions (empty frames) | median ms | p95 ms | CPU ms median | CPU ms p95 "
          "| load |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    base = HeldoutSequence(width=width, height=height, duration_s=duration_s)
    for name in names or list(CONDITIONS):
        seq = base.with_conditions(CONDITIONS[name])
        ours = OcclusionProcessor(_flat_camera(width, height))
        mog2 = cv2.createBackgroundSubtractorMOG2(history=200, varThreshold=16,
                                                  detectShadows=True)
        methods = {"ours": ours.process, "mog2": functools.partial(mog2_open_close, mog2)}
        if before is not None:
            methods["before"] = before(_flat_camera(width, height)).process
        res = {k: {"iou": [], "shadow": 0, "kept": 0, "phantom": [], "ms": [], "cpu": []}
               for k in methods}
        shadow_all = 0
        for i, f in enumerate(seq.frames()):
            masks, learning = {}, False
            order = list(methods.items())
            for k, fn in order if i % 2 else order[::-1]:  # the load hits them alike
                out, ms, cpu = cpu_timed(fn, f.image)
                if k == "mog2":
                    masks[k] = out
                else:
                    masks[k] = out.person_mask > 0
                    learning = out.learning
                res[k]["ms"].append(ms)
                res[k]["cpu"].append(cpu)
            if learning:
                for t in res.values():
                    del t["ms"][-1], t["cpu"][-1]
                continue
            shadow_all += np.count_nonzero(f.shadow)
            for k, m in masks.items():
                if f.people == 0 and not f.person.any():
                    res[k]["phantom"].append(regions(m))
                    continue
                union = np.count_nonzero(m | f.person)
                res[k]["iou"].append(np.count_nonzero(m & f.person) / max(union, 1))
                res[k]["shadow"] += np.count_nonzero(m & f.shadow)
        labels = {"ours": "ours", "mog2": "MOG2 + open/close", "before": f"ours at {sha}"}
        for k in res:
            t, label = res[k], labels[k]
            print(f"| {name} | {label} | {statistics.median(t['iou']):.3f} | "
                  f"{min(t['iou']):.3f} | {t['shadow'] / max(shadow_all, 1):.3f} | "
                  f"{sum(t['phantom'])} in {len(t['phantom'])} (max {max(t['phantom'])}) | "
                  f"{statistics.median(t['ms']):.1f} | {np.percentile(t['ms'], 95):.1f} | "
                  f"{statistics.median(t['cpu']):.1f} | {np.percentile(t['cpu'], 95):.1f} | "
                  f"{os.getloadavg()[0]:.1f} |", flush=True)


def synthetic(sizes=((480, 270), (1024, 512))) -> None:
    """Issue 18's figures on the standard sequence, new (broadband) and old (narrow-band)."""
    import dataclasses

    from tests.server.occlusion.conftest import CODEC_EMPTY_S, CODECS, coded_truths

    print("\nStandard sequence, 12 s at 10 frames/s, 1.6 s empty (1 s learned): broadband "
          "(now) and narrow-band (before 2026-11-25) light, raw and coded\n")
    print("| size | light | frames as | person IoU (median) | worst frame IoU | shadow kept | "
          "phantom regions (empty frames) | draw ms/frame | CPU ms median | CPU ms p95 | load |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for width, height in sizes:
        for light in ("broadband", "narrowband"):
            site = dataclasses.replace(default_site(width, height, empty_s=CODEC_EMPTY_S),
                                       light_model=light)
            virtual = box_depth_image(site.camera, *VIRTUAL_BOX)
            c0 = time.process_time()
            for i in range(site.frame_count):
                site.frame(i)
            draw_ms = 1e3 * (time.process_time() - c0) / site.frame_count
            for name, codec in CODECS.items():
                ours = OcclusionProcessor(site.camera, virtual)
                iou, phantom, cpu = [], [], []
                shadow = kept = 0
                for truth in coded_truths(site, codec):
                    r, _, ms = cpu_timed(ours.process, truth.image, truth.time_s)
                    if r.learning:
                        continue
                    cpu.append(ms)
                    person = r.person_mask > 0
                    shadow += np.count_nonzero(truth.shadow)
                    kept += np.count_nonzero(truth.shadow & person)
                    if truth.person.any():
                        iou.append(np.count_nonzero(person & truth.person)
                                   / np.count_nonzero(person | truth.person))
                    else:
                        phantom.append(regions(person))
                print(f"| {width}x{height} | {light} | {name} | {statistics.median(iou):.3f} | "
                      f"{min(iou):.3f} | {kept / max(shadow, 1):.3f} | {sum(phantom)} in "
                      f"{len(phantom)} (max {max(phantom)}) | {draw_ms:.1f} | "
                      f"{statistics.median(cpu):.1f} | {np.percentile(cpu, 95):.1f} | "
                      f"{os.getloadavg()[0]:.1f} |", flush=True)


# Issue 18's codec work (2026-11-25) switched off: the detector as it was before, for the
# same-run baseline of --codecs (these settings reproduce its figures exactly).
BEFORE_CODEC_WORK = {"shadow_learn_spread": False, "codec_chroma_px": 1,
                     "shadow_sliver_share": 0.0, "shadow_ratio": (0.15, 0.92),
                     "outline_radius_px": 0, "shadow_island_share": 0.0}
# The outline work of 2026-11-25 (outline.py, shadowpieces.py's islands) switched off: the
# detector as the codec work left it, the same-run baseline of the outlines.
BEFORE_OUTLINES = {"outline_radius_px": 0, "shadow_island_share": 0.0}
# The standing-height rule (depth.drop_flat_regions) and the shadow-deviation limit of
# 2026-11-25 (branch s25-h264) switched off: the detector as the outline work left it.
BEFORE_STANDING = {"min_person_height_m": 0.0, "shadow_max_deviation": 0.0}


def codecs(sizes=((480, 270), (1024, 512)), baseline: str | None = None) -> None:
    """Issue 18's figures through the codecs, the detector after its codec work, after its
    outline work and now (or, with ``baseline``, that revision's detector and now),
    interleaved frame by frame on the same frames (same run, same load)."""
    from server.occlusion.settings import OcclusionSettings
    from tests.server.occlusion.conftest import CODEC_EMPTY_S, CODECS, coded_truths

    variants = {"codec work": OcclusionSettings(**BEFORE_OUTLINES, **BEFORE_STANDING),
                "outline work": OcclusionSettings(**BEFORE_STANDING), "now": OcclusionSettings()}
    compared = (f"the detector after issue 18's codec work (settings "
                f"{BEFORE_OUTLINES | BEFORE_STANDING}), after the outline work "
                f"({BEFORE_STANDING}) and now")
    before = None
    if baseline:  # the detector of another revision instead of the settings variants
        before, sha = baseline_processor(baseline)
        variants = {f"at {sha}": None, "now": OcclusionSettings()}
        compared = (f"the detector at {sha} and now, interleaved frame by frame, each first "
                    "in turn")
    print("\nStandard sequence (broadband), 12 s at 10 frames/s, 1.6 s empty (1 s learned), "
          f"raw and coded: {compared}\n")
    print("| size | frames as | detector | person IoU (median) | worst frame IoU | "
          "shadow kept | phantom regions (empty frames) | CPU ms median | CPU ms p95 | load |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for width, height in sizes:
        site = default_site(width, height, empty_s=CODEC_EMPTY_S)
        virtual = box_depth_image(site.camera, *VIRTUAL_BOX)
        for name, codec in CODECS.items():
            procs = {k: (before(site.camera, virtual) if v is None
                         else OcclusionProcessor(site.camera, virtual, v))
                     for k, v in variants.items()}
            res = {k: {"iou": [], "phantom": [], "cpu": [], "kept": 0} for k in variants}
            shadow = 0
            for i, truth in enumerate(coded_truths(site, codec)):
                learning = False
                order = list(procs.items())
                for k, proc in order if i % 2 or before is None else order[::-1]:
                    r, _, ms = cpu_timed(proc.process, truth.image, truth.time_s)
                    learning = r.learning
                    if learning:
                        continue
                    t = res[k]
                    t["cpu"].append(ms)
                    person = r.person_mask > 0
                    t["kept"] += np.count_nonzero(truth.shadow & person)
                    if truth.person.any():
                        t["iou"].append(np.count_nonzero(person & truth.person)
                                        / np.count_nonzero(person | truth.person))
                    else:
                        t["phantom"].append(regions(person))
                if not learning:
                    shadow += np.count_nonzero(truth.shadow)
            for k, t in res.items():
                print(f"| {width}x{height} | {name} | {k} | {statistics.median(t['iou']):.3f} | "
                      f"{min(t['iou']):.3f} | {t['kept'] / max(shadow, 1):.3f} | "
                      f"{sum(t['phantom'])} in {len(t['phantom'])} (max {max(t['phantom'])}) | "
                      f"{statistics.median(t['cpu']):.1f} | {np.percentile(t['cpu'], 95):.1f} | "
                      f"{os.getloadavg()[0]:.1f} |", flush=True)


def refit(repeats: int = 200) -> None:
    """The person colour mixture's warm refit (300 samples, 5 components, at most 5 EM steps):
    this code's numpy EM against OpenCV's ``EM.trainM`` from the same posteriors, interleaved
    call by call on one core, and the look-up table built after each refit."""
    from server.occlusion.mixture import ColourMixture, em_from_posteriors

    rng = np.random.default_rng(18)
    centres = rng.uniform(30, 220, (5, 3))
    base = np.concatenate([c + rng.normal(size=(60, 3)) @ (rng.normal(size=(3, 3)) * 6.0)
                           for c in centres])
    mix = ColourMixture(5, max_iter=5)
    assert mix.fit(base, warm=False)
    cpu: dict[str, list[float]] = {"numpy EM (ours)": [], "cv2.ml.EM.trainM": [],
                                   "table (32768 bins)": []}
    worst = 0.0
    for i in range(repeats):
        x = base + rng.normal(0, 3, base.shape)  # colours drifting between refits
        logs = mix._component_logs(np.ascontiguousarray(x.T))
        probs = np.exp(logs - logs.max(axis=0))
        probs = np.ascontiguousarray((probs / probs.sum(axis=0)).T)
        em = cv2.ml.EM_create()
        em.setClustersNumber(5)
        em.setCovarianceMatrixType(cv2.ml.EM_COV_MAT_GENERIC)
        em.setTermCriteria((cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 5, 1e-3))
        calls = [("numpy EM (ours)", em_from_posteriors, (x, probs, 5, 1e-3)),
                 ("cv2.ml.EM.trainM", em.trainM, (x, probs))]
        for name, fn, args in calls if i % 2 else calls[::-1]:
            out, _, ms = cpu_timed(fn, *args)
            cpu[name].append(ms)
            if name.startswith("numpy"):
                ours_means = out[0]
        worst = max(worst, float(np.abs(ours_means - em.getMeans()).max()))
        _, _, ms = cpu_timed(mix.table, 5, 0.3)
        cpu["table (32768 bins)"].append(ms)
    print(f"\nPerson mixture refit, {repeats} refits on one core, load average "
          f"{os.getloadavg()[0]:.1f}; largest difference of the means, ours against OpenCV: "
          f"{worst:.1e} codes\n")
    print("| step | CPU ms median | CPU ms p95 |")
    print("|---|---:|---:|")
    for name, v in cpu.items():
        print(f"| {name} | {statistics.median(v):.2f} | {np.percentile(v, 95):.2f} |")


def _flat_camera(width: int, height: int):
    """The held-out camera for ours (depth is not measured here, only the person mask)."""
    from server.occlusion.synthetic import make_camera

    return make_camera(width, height)


def parse_args(argv: list[str] | None = None):
    """The command line (``--help`` prints it and runs nothing)."""
    import argparse

    from tests.server.occlusion.heldout import CONDITIONS

    ap = argparse.ArgumentParser(
        description="Occlusion by visitors: ms per site-camera frame and accuracy, on one "
                    "core (issue 6; held-out sequences of issue 18).")
    ap.add_argument("--ablation", action="store_true",
                    help="also print the ablation on the 480x270 standard sequence")
    ap.add_argument("--heldout", action="store_true",
                    help="the held-out sequences instead of the standard one (about 15 min "
                         "for all conditions)")
    ap.add_argument("--synthetic", action="store_true",
                    help="only the standard sequence, broadband and narrow-band light, raw, "
                         "JPEG 75 and H.264 (issue 18; a few minutes)")
    ap.add_argument("--codecs", action="store_true",
                    help="issue 18's figures through JPEG 75 and H.264, the detector before "
                    "and after its codec work, same run")
    ap.add_argument("--baseline", metavar="REV",
                    help="with --codecs or --heldout, also run the detector of git revision "
                         "REV (e.g. main), interleaved frame by frame: a same-run baseline")
    ap.add_argument("--refit", action="store_true",
                    help="only the person colour refit: numpy EM against OpenCV's trainM "
                         "(seconds)")
    ap.add_argument("conditions", nargs="*", metavar="CONDITION",
                    help="with --heldout, only these conditions (quote names with spaces); "
                         "one of: " + ", ".join(CONDITIONS))
    args = ap.parse_args(argv)
    if args.baseline and not (args.codecs or args.heldout):
        ap.error("--baseline needs --codecs or --heldout")
    unknown = [c for c in args.conditions if c not in CONDITIONS]
    if unknown or (args.conditions and not args.heldout):
        ap.error(f"conditions need --heldout and one of {list(CONDITIONS)}; "
                 f"got {unknown or args.conditions}")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.refit:
        refit()
        return
    if args.heldout:
        heldout(args.conditions or None, baseline=args.baseline)
        return
    if args.synthetic:
        synthetic()
        return
    if args.codecs:
        codecs(baseline=args.baseline)
        return
    print("Occlusion pipeline, one core (cv2.setNumThreads(1), BLAS/OpenMP threads 1)")
    for width, height in SIZES:
        run(width, height)
    if args.ablation:
        ablation()


if __name__ == "__main__":
    main()
