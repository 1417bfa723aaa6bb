"""The viewer's review panel: list, select, flip and save the filter's candidates.

Built by :func:`clearsplat.viewer.serve` for a filter output that keeps its candidates. Every
change goes through :mod:`clearsplat.review`, as ``clearsplat edit`` does: the verdicts flipped
here are an edit of the loaded folder (:meth:`Review.edits`), the scene shows
:func:`~clearsplat.review.edit_removed` of it, and "Save" runs
:func:`~clearsplat.review.edit_filter_output`.
"""

from __future__ import annotations

import html
import math
import os

import numpy as np

from .errors import ClearsplatError
from .review import edit_command, edit_filter_output, edit_removed

#: The "List" filter's choices.
LISTS = ("all", "accepted", "rejected", "edited")
_NONE = "(choose a candidate)"
_ROWS = 60                              # rows of the table (the dropdown lists them all)


def _score(c: dict) -> float:
    s = c.get("scores", {}).get("individual")
    return -math.inf if s is None or not math.isfinite(s) else float(s)


class Review:
    """The panel of one viewer and one filter output (see the module docstring).

    Attributes
    ----------
    output : clearsplat.review.FilterOutput
        The folder as loaded.
    verdicts : (K,) bool
        The verdicts now.
    removed : (N,) bool
        The removal now (``edit_removed`` of the loaded folder's by :meth:`edits`).
    selected : int or None
    """

    def __init__(self, viewer, output, keep):
        self.viewer, self.output = viewer, output
        self.verdicts = output.accepted.copy()
        self.removed = output.removed.copy()
        self.selected = None
        self.saved = None               # (record, command) of the last save
        sets, n = output.sets, output.removed.size
        # the Gaussian -> candidate map of clicks: the best-scoring candidate wins a Gaussian
        self.owner = np.full(n, -1, np.int64)
        for k in sorted(range(len(sets)), key=lambda k: _score(output.candidates[k])):
            self.owner[sets.removal(k)] = k
        self._build(viewer.server, output)
        self.update_list()

        @viewer.server.scene.on_click()
        def _(event) -> None:
            k = self.pick(event.ray_origin, event.ray_direction)
            if k is not None:
                self.select(k)

    # -- GUI -----------------------------------------------------------------------------------
    def _build(self, server, output) -> None:
        gui = server.gui
        views = sorted({int(v) for v in output.sets.view})
        with gui.add_folder("Review"):
            self.info = gui.add_markdown("")
            self.list_filter = gui.add_dropdown("List", LISTS, initial_value="all")
            self.view_filter = gui.add_dropdown(
                "View", ["all views"] + [f"view {v}" for v in views], initial_value="all views")
            self.choice = gui.add_dropdown("Candidate", [_NONE], initial_value=_NONE)
            self.accepted = gui.add_checkbox("Accepted (removed)", initial_value=False,
                                             disabled=True)
            self.crops = gui.add_image(np.zeros((8, 24, 3), np.uint8),
                                       label="input | before | after", format="png")
            self.table = gui.add_html("")
            self.out_text = gui.add_text("Save to", initial_value=os.fspath(
                output.folder.parent / f"{output.folder.name}-edited"))
            self.force = gui.add_checkbox("Replace it (--force)", initial_value=False)
            self.save_button = gui.add_button("Save edited folder")
            self.status = gui.add_markdown("")
        for handle in (self.list_filter, self.view_filter):
            handle.on_update(lambda _e: self.update_list())

        @self.choice.on_update
        def _(_e) -> None:
            k = self._index_of(self.choice.value)
            if k is not None and k != self.selected:
                self.select(k)

        @self.accepted.on_update
        def _(_e) -> None:
            if self.selected is not None and self.accepted.value != self.verdicts[self.selected]:
                self.set_verdict(self.selected, self.accepted.value)

        @self.save_button.on_click
        def _(_e) -> None:
            try:
                self.save(self.out_text.value, force=self.force.value)
            except ClearsplatError as e:
                self.status.content = f"**Not saved:** {html.escape(str(e))}"

    def label(self, k: int) -> str:
        c = self.output.candidates[k]
        verdict = "accepted" if self.verdicts[k] else "rejected"
        edited = " (edited)" if self.verdicts[k] != self.output.accepted[k] else ""
        score = _score(c)
        return (f"#{k} · view {c['view']} · {self.output.sets.removal(k).size:,} G · "
                f"{score:+.3f} · {verdict}{edited} · round {c.get('round', 1)}")

    @staticmethod
    def _index_of(label: str):
        if not label.startswith("#"):
            return None
        return int(label[1:].split(" ", 1)[0])

    def listed(self) -> list:
        """The candidates the filters let through, best individual score first."""
        which, view = self.list_filter.value, self.view_filter.value
        out = []
        for k, c in enumerate(self.output.candidates):
            if view != "all views" and f"view {c['view']}" != view:
                continue
            edited = self.verdicts[k] != self.output.accepted[k]
            if (which == "accepted" and not self.verdicts[k]) or \
                    (which == "rejected" and self.verdicts[k]) or (which == "edited" and not edited):
                continue
            out.append(k)
        return sorted(out, key=lambda k: (-_score(self.output.candidates[k]), k))

    def update_list(self) -> None:
        """Refresh the dropdown, the table and the counts after a change."""
        ks = self.listed()
        labels = [_NONE] + [self.label(k) for k in ks]
        self.choice.options = labels
        current = self.label(self.selected) if self.selected in ks else _NONE
        if self.choice.value != current:
            self.choice.value = current
        reject, accept = self.edits()
        self.info.content = (
            f"**{len(self.verdicts)} candidates**, {int(self.verdicts.sum())} accepted; "
            f"{int(self.removed.sum()):,} Gaussians removed. Edits: "
            + (f"reject {_ids(reject)}; " if reject else "")
            + (f"accept {_ids(accept)}" if accept else "" if reject else "none")
            + ". Click a splat to select its candidate.")
        self.table.content = self._table(ks)

    def _table(self, ks) -> str:
        rows = []
        for k in ks[:_ROWS]:
            c = self.output.candidates[k]
            s = c.get("scores", {})
            cells = [k, c["view"], f"{self.output.sets.removal(k).size:,}"] + [
                "" if s.get(t) is None else f"{s[t]:+.3f}"
                for t in ("individual", "additional", "joint")] + [
                ("accepted" if self.verdicts[k] else "rejected")
                + ("*" if self.verdicts[k] != self.output.accepted[k] else ""),
                c.get("round", 1)]
            style = ' style="background:#1f4d2a"' if k == self.selected else ""
            rows.append(f"<tr{style}>" + "".join(f"<td>{html.escape(str(v))}</td>"
                                                 for v in cells) + "</tr>")
        more = f"<p>and {len(ks) - _ROWS} more</p>" if len(ks) > _ROWS else ""
        head = "".join(f"<th>{h}</th>" for h in ("#", "view", "G", "indiv.", "add.", "joint",
                                                  "verdict", "round"))
        return (f'<div style="max-height:14em;overflow:auto;font-size:0.75em">'
                f"<table><tr>{head}</tr>{''.join(rows)}</table>{more}</div>")

    # -- actions -------------------------------------------------------------------------------
    def select(self, k: int) -> None:
        """Select candidate ``k``: highlight it, look through its view, show its crops."""
        if not 0 <= k < len(self.verdicts):
            raise ClearsplatError(f"no candidate {k}", field="select")
        self.selected = k
        self.viewer.highlight = self.output.sets.removal(k)
        self.accepted.disabled = False
        self.accepted.value = bool(self.verdicts[k])
        self.viewer.refresh()
        self.viewer.look_through(int(self.output.sets.view[k]))
        self.crops.image = self.crop_images(k)
        self.update_list()

    def set_verdict(self, k: int, accepted: bool) -> None:
        """Accept or reject candidate ``k``; the scene follows at once."""
        self.verdicts[k] = accepted
        reject, accept = self.edits()
        self.removed, _ = edit_removed(self.output.removed, self.output.sets,
                                       self.output.accepted, reject=reject, accept=accept)
        self.viewer.keep = ~self.removed
        if self.accepted.value != accepted and self.selected == k:
            self.accepted.value = accepted
        self.viewer.refresh()
        if self.selected is not None:
            self.crops.image = self.crop_images(self.selected)
        self.update_list()

    def flip(self, k: int | None = None) -> None:
        """Toggle the verdict of candidate ``k`` (default: the selected one)."""
        k = self.selected if k is None else k
        if k is None:
            raise ClearsplatError("no candidate selected", field="select")
        self.set_verdict(k, not self.verdicts[k])

    def edits(self) -> tuple[list, list]:
        """(reject, accept): the candidates whose verdict differs from the loaded folder's."""
        changed = self.verdicts != self.output.accepted
        return (np.flatnonzero(changed & ~self.verdicts).tolist(),
                np.flatnonzero(changed & self.verdicts).tolist())

    def save(self, out, *, force: bool = False) -> str:
        """Write the edited folder ``out`` as ``clearsplat edit`` does; return (and print) the
        equivalent command."""
        reject, accept = self.edits()
        record = edit_filter_output(self.output.folder, out, reject=reject, accept=accept,
                                    force=force)
        command = edit_command(self.output.folder, out, reject=reject, accept=accept,
                               force=force)
        self.saved = (record, command)
        print(f"clearsplat viewer: wrote {out}; the same as: {command}", flush=True)
        self.status.content = (f"Wrote {html.escape(os.fspath(out))} (restored "
                               f"{record['restored']:,}, removed {record['removed']:,}). "
                               f"The same as:\n\n`{command}`")
        return command

    # -- picking and crops ---------------------------------------------------------------------
    def pick(self, origin, direction):
        """The candidate whose Gaussian a click ray meets first, or None.

        A Gaussian is met when the ray passes within two of its largest standard deviations
        of its centre, or within 0.005 rad of it as seen from the ray's origin.
        """
        idx = np.flatnonzero(self.owner >= 0)
        if idx.size == 0:
            return None
        o = np.asarray(origin, np.float64)
        d = np.asarray(direction, np.float64)
        d = d / (np.linalg.norm(d) or 1.0)
        g = self.viewer.scene.gaussians
        p = g.means[idx].astype(np.float64) - o
        t = p @ d
        off = np.linalg.norm(p - t[:, None] * d, axis=1)
        reach = np.maximum(2.0 * g.scales[idx].max(axis=1), 0.005 * t)
        hit = (t > 0) & (off <= reach)
        if not hit.any():
            return None
        return int(self.owner[idx[hit][np.argmin(t[hit])]])

    def crop_images(self, k: int, *, height: int = 96) -> np.ndarray:
        """(h, w, 3) uint8: the input crop of candidate ``k`` (its region outlined), the render
        with its Gaussians (before) and without them (after), side by side."""
        from PIL import Image

        from .render import render

        scene = self.viewer.scene
        view = int(self.output.sets.view[k])
        cam = scene.cameras[view]
        region = self.output.sets.pixels(k, (cam.height, cam.width))
        r0, c0, r1, c1 = (int(v) for v in self.output.sets.boxes[k])
        if r1 <= r0:
            r0, c0, r1, c1 = 0, 0, cam.height, cam.width
        pad = max(4, (r1 - r0 + c1 - c0) // 4)
        r0, c0 = max(0, r0 - pad), max(0, c0 - pad)
        r1, c1 = min(cam.height, r1 + pad), min(cam.width, c1 + pad)
        crop = _crop_camera(cam, r0, c0, r1, c1)
        gone = np.zeros(len(self.removed), bool)
        gone[self.output.sets.removal(k)] = True
        before = render(scene, crop, keep=~self.removed | gone).rgb
        after = render(scene, crop, keep=~self.removed & ~gone).rgb
        if scene.images is not None:
            image = scene.images[view][r0:r1, c0:c1].copy()
        else:
            image = np.full_like(before, 0.3)
        m = region[r0:r1, c0:c1]
        edge = m & ~(np.roll(m, 1, 0) & np.roll(m, -1, 0) & np.roll(m, 1, 1) & np.roll(m, -1, 1))
        image[edge] = (0.1, 1.0, 0.25)
        gap = np.ones((image.shape[0], 2, 3), np.float32)
        strip = np.concatenate([image, gap, before, gap, after], axis=1)
        strip = (np.clip(strip, 0, 1) * 255 + 0.5).astype(np.uint8)
        scale = max(1, round(height / strip.shape[0]))
        if scale > 1:
            strip = np.asarray(Image.fromarray(strip).resize(
                (strip.shape[1] * scale, strip.shape[0] * scale), Image.NEAREST))
        return strip


def _crop_camera(cam, r0: int, c0: int, r1: int, c1: int):
    """The camera that sees pixels ``[r0:r1, c0:c1]`` of ``cam`` (principal point shifted)."""
    from .cameras import Camera
    K = np.array(cam.K, np.float64)
    K[0, 2] -= c0
    K[1, 2] -= r0
    return Camera(K=K, camera_to_world=cam.camera_to_world, width=c1 - c0, height=r1 - r0)


def _ids(ids) -> str:
    return ",".join(str(k) for k in ids)
