"""Writing a final render into Blender's RenderResult: rows of the film as sub-results with every pass, the
denoised Combined, and the metadata stamped on the whole result.

Image rows are written with row 0 at the top; Blender's rows go bottom-up, so they are flipped once here
(_set_rect). Sub-results are begun relative to the border region when there is one.
"""
from __future__ import annotations

import numpy as np

from . import cryptomatte

# Rows go to Blender in sub-results of at most this many pixels (4 MB of float32 RGBA each).
WRITE_CHUNK_PIXELS = 1 << 18


class ResultWriter:
    """Writes one view layer's result of a final render (FinalRender in engine/session.py)."""

    def __init__(self, engine, layer: str):
        self.engine = engine
        self.layer = layer          # the view layer's name
        self.view = ""              # the multi-view render's view being written ("": the only one)
        self.passes = []            # engine.passes.Pass, besides Combined

    def write_rows(self, film, row0: int, row1: int, cols: slice | None = None,
                   denoised: np.ndarray | None = None, denoised_passes: dict | None = None) -> None:
        """Region rows [row0, row1) (row 0 at the top) and columns cols (None: all) -> a sub-result of
        Blender's (rows bottom-up, coordinates relative to the border region when there is one), with every
        pass: Blender merges each pass of a sub-result, written or not. denoised: the (rows, cols, 3) colour
        to write as Combined with the film's alpha, or (rows, cols, 4) all of it (the film's own then goes to
        Noisy Image); denoised_passes: other passes' denoised values by pass name (the film's own then go to
        their Noisy passes)."""
        cols = slice(0, film.width) if cols is None else cols
        rows = film.resolve(row0, row1)[:, cols]
        if denoised is None or denoised.shape[-1] == 4:
            combined = rows if denoised is None else denoised
        else:
            combined = np.concatenate([denoised, rows[..., 3:]], axis=-1)
        denoised_passes = denoised_passes or {}
        result = self.engine.begin_result(cols.start, film.height - row1, cols.stop - cols.start, row1 - row0,
                                          layer=self.layer, view=self.view)
        try:
            layer = result.layers[0]
            _set_rect(layer, "Combined", combined)
            crypto = {}
            for p in self.passes:
                if p.kernel.startswith("crypto:"):
                    _, kind, index = p.kernel.split(":")
                    if kind not in crypto:
                        crypto[kind] = film.resolve_crypto(kind, row0, row1)[:, cols]
                    _set_rect(layer, p.name, crypto[kind][..., 4 * int(index):4 * int(index) + 4])
                elif p.name in denoised_passes:
                    _set_rect(layer, p.name, denoised_passes[p.name])
                elif p.kernel:
                    values = film.resolve_pass(p.kernel, row0, row1)[:, cols]
                    if p.channels == 4 and values.shape[-1] == 3:  # an RGBA AOV: opaque
                        values = np.concatenate([values, np.ones(values.shape[:-1] + (1,), np.float32)], axis=-1)
                    _set_rect(layer, p.name, values)
                else:
                    _set_rect(layer, p.name, rows)

        finally:
            self.engine.end_result(result)

    def write_combined(self, image: np.ndarray, film) -> None:
        """The whole region's Combined pass (the denoised image), in chunks of rows."""
        step = max(1, WRITE_CHUNK_PIXELS // max(film.width, 1))
        for row0 in range(0, film.height, step):
            row1 = min(film.height, row0 + step)
            result = self.engine.begin_result(0, film.height - row1, film.width, row1 - row0, layer=self.layer,
                                              view=self.view)
            try:
                _set_rect(result.layers[0], "Combined", image[row0:row1])
            finally:
                self.engine.end_result(result)

    def stamp_metadata(self, film, denoised: bool, ember, crypto_names: dict) -> None:
        """The render's metadata (on Blender's whole result, as Cycles stamps its own): the samples it holds
        and their offset (python -m ember merge weighs partial renders by them), and the Cryptomatte
        manifests of crypto_names, kind -> names (the compositor's Cryptomatte node and other tools read
        names from them). ember : the scene's Ember settings."""
        full = self.engine.get_result()
        if full is None:
            return
        full.stamp_data_add_field("ember.samples", str(film.samples_done))
        full.stamp_data_add_field("ember.sample_offset", str(int(ember.sample_offset)))
        full.stamp_data_add_field("ember.adaptive", "1" if ember.use_adaptive_sampling else "0")
        full.stamp_data_add_field("ember.denoised", "1" if denoised else "0")
        for kind in film.crypto:
            for key, value in cryptomatte.metadata(self.layer, kind, crypto_names.get(kind, ())).items():
                full.stamp_data_add_field(key, value)


def _set_rect(layer, name: str, rows: np.ndarray) -> None:
    """Rows (row 0 at the top) into a render result pass (Blender's rows go bottom-up)."""
    target = layer.passes.get(name)
    if target is not None:
        target.rect.foreach_set(np.ascontiguousarray(rows[::-1], dtype=np.float32).ravel())
