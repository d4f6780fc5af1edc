"""How a build's stacks are compressed: the settings (``[compression]`` of the scene file,
docs/scene-format.md), each default with the measurement behind it (docs/benchmarks.md,
"Figures behind choices in the code"). Used by bake.compress, bake.stackkinds, bake.sunbounce
and bake.basisu."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Settings:
    """How a build's stacks are compressed. The measurements behind each default are in
    docs/benchmarks.md, "Figures behind choices in the code"."""

    budget: float = 0.01  # RMS error over the mean on every test sky
    max_rank: int = 64
    encoding: str = "uastc"
    # One: the sun's patch. Selecting its brightest neighbours too raised k on every stack:
    # zeroing them leaves holes around the sun in r', which the smooth base then has to draw;
    # their own light is smooth, and the base sums it well.
    selected_lights: int = 1
    # UASTC levels: level 0 for coarse layers (level 2 is far slower for little less error);
    # level 1 for refinement layers (noise-like), where it cuts the worst texel of a shadow
    # edge for a few per cent more bytes, as level 2 does at several times the time.
    uastc_level: int = 0  # coarse light images
    refine_level: int = 1  # refinement layers, and arrays holding both stages
    # A sun-bounce coarse image over ``sun_bounce_budget`` as displayed (below) at
    # ``uastc_level`` is encoded again at this level before it is given a refinement: on the
    # 400-light final lightmap level 1's images were 7 % larger and 12 % closer, and spared
    # 24 of 142 refinements, each larger than the coarse image (docs/benchmarks.md,
    # "Downloads with the sun apart").
    sun_bounce_level: int = 1
    # "smallest": a judged sun-bounce image is also encoded with ETC1S (quality 255) and with
    # UASTC at uastc_level with rate-distortion optimization (``sun_bounce_rdo_lambdas``, in
    # turn), and keeps the first of those that is smaller than its plain UASTC image and
    # within ``sun_bounce_budget`` as displayed, its RMS and at single texels
    # (bake.sundisplay.TEXEL_BOUND_PER_BUDGET: these codecs' errors are blocky, and an RMS
    # lets them gather in shade; where plain UASTC's own is over that bound, as on the
    # models' faces, within bake.sunbounce.PLAIN_TEXEL_SLACK of plain's own); the others go
    # on to plain UASTC as above. The default since 2026-12-07: the ground's and the smooth
    # stacks' images fit, and since that afternoon the models' faces' with lambda 0.1
    # (docs/benchmarks.md, "Sharing and cheaper codecs held at single texels", "The phone's
    # visit under 4 MB"); the kiosk's views keep plain UASTC (bake.sunbounce.view_settings).
    # "uastc": plain UASTC only.
    sun_bounce_encoding: str = "smallest"
    sun_bounce_rdo_lambdas: tuple[float, ...] = (3.0, 1.0, 0.1)
    # basisu's RDO dictionary (-uastc_rdo_d) for those encodings: 2048 bytes instead of the
    # encoder's 4096 makes an RDO encode about a third faster for a fraction of a per cent
    # more bytes (docs/benchmarks.md, "The RDO dictionary").
    sun_bounce_rdo_dictionary_bytes: int = 2048
    # The same for stacks judged by their RMS error alone (lightmap, views): a refinement
    # layer spans a few steps of its coarse layer, so level 1's better worst texel does not
    # show there, and level 0 is faster.
    rms_refine_level: int = 0
    # A sun-bounce image whose coarse level alone is within this RMS error of the displayed
    # value (sky without the disc, the sun's direct term and its bounce, clear sky, the sun
    # at the patch's centre; the direct term since 2026-12-06 afternoon) gets no refinement
    # (bake.sunbounce; docs/compact-assets.md, "The sun's bounce").
    # None: every image keeps its refinement, as before 2026-11-25.
    sun_bounce_budget: float | None = 0.01
    # The sun's bounce is kept at no finer an angular step than a dome of about this many
    # lights: on a finer dome neighbouring sun-path patches share one sun-bounce image, their
    # solid-angle mean (the patches whose centroids lie in one patch of that dome;
    # bake.sunshare.SharedImages). None: one image per patch, as before 2026-12-06. At 400
    # lights a two-hour visit then fetches 3 images per stack instead of 6 (docs/sun.md,
    # "Shared images"; what it costs in fidelity: docs/benchmarks.md).
    sun_bounce_lights: int | None = 196
    # "within_budget": a patch shares its group's image only where that, at its own gain,
    # keeps it within bake.sunshare.SHARING_SHARE of ``sun_bounce_budget`` as displayed, its
    # RMS and at single texels (bake.sundisplay.TEXEL_BOUND_PER_BUDGET, since 2026-12-07),
    # else it gets an image of its own (bake.sunshare.groups_within; since 2026-12-06
    # night). "always": every member of a group shares it, as before (fewer bytes, over the
    # budget for most patches of the models' faces at 400 lights: docs/benchmarks.md, "Each
    # patch's own gain, and sharing only within the budget").
    sun_bounce_sharing: str = "within_budget"
    # Zstandard supercompression of the UASTC blocks (lossless): level 19 for arrays (the
    # base layers every phone downloads: 15 made them larger), 15 for separate light images
    # (less encode time for a fraction of a per cent more bytes).
    zstd_level: int = 19
    image_zstd_level: int = 15
    # Base layers from this coefficient on (with UASTC) go into a second array encoded with
    # ETC1S (quality 255), unrefined: their coefficients are small, so ETC1S's coarser blocks
    # weigh little, and an ETC1S layer is several times smaller. Why 8 and not fewer (the
    # ground's shadow ratio): docs/benchmarks.md, "Downloads with the sun apart". None:
    # every layer UASTC.
    etc1s_from_layer: int | None = 8
    # The same for stacks judged by their RMS error alone (lightmap, views: no shadow ratio
    # to keep), tried first; while the decoded composite is over the budget on a test sky,
    # the stack is encoded again with the ETC1S array one layer later, up to
    # ``etc1s_from_layer``, then with no ETC1S layer
    # (:func:`bake.stackkinds.compress_rms_stack`; straight from 4 to 8, the 400-light final
    # lightmap fell back to 8 for 0.05 % over the budget where 5 was within it and 0.61 MB
    # smaller). Measured: docs/benchmarks.md, "Downloads with the sun apart".
    rms_etc1s_from_layer: int | None = 4
    # Which base layers of a stack judged by its RMS error alone are refined: the fewest
    # that keep its decoded composite within this share of the budget on every test sky
    # (refinement.layers_to_refine_within; the rest of the budget is the refinements' own
    # residual's and a margin for skies that did not choose them). None: every layer whose
    # own loss passes a tenth of the budget on some sky (refinement.layers_to_refine), as
    # before 2026-12-05, which refined four layers of the 400-light final lightmap that the
    # budget did not need (docs/benchmarks.md, "issue 15, 2026-12-05").
    rms_refine_target: float | None = 0.9
    # No rate-distortion optimization (basisu -uastc_rdo_l): it shrinks coarse light images
    # but refinements are most of the light bytes, so over a bake it saved little of a
    # phone's download for about half of the bake's time.
