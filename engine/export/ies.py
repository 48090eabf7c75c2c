"""IES LM-63 photometric files -> kernels.shading.ies.IesTable, as Cycles reads them (util/ies.cpp IESFile::parse
and process): the numbers after the TILT line (commas count as spaces), the candela values times the
candela multiplier, the ballast factors and 4 pi / 177.83 (candela to W/sr at the D65 illuminant's luminous
efficacy), and the angles turned into Cycles' layout: vertical angles from straight down over [0, 180] degrees,
horizontal ones over [0, 360] by the symmetries photometric types A, B and C allow. None when the text is not a
usable IES file (Cycles then gives the node 100 x its Strength).
"""
from __future__ import annotations

import numpy as np

from ...kernels.shading.ies import IesTable

CANDELA_TO_WATT = 0.0706650768394   # 4 pi / 177.83
TYPE_C, TYPE_B, TYPE_A = 1, 2, 3


def _close(a: float, b: float) -> bool:
    return abs(a - b) < 1e-4


def _numbers(text: str):
    """The numbers after the TILT line, or None when there is no TILT line."""
    text = text.replace(",", " ")
    at = text.find("\nTILT=")
    if at < 0:
        return None
    rest = text[at:]
    if rest.startswith("\nTILT=INCLUDE"):
        words = rest[len("\nTILT=INCLUDE"):].split()
        try:
            count = int(float(words[1]))      # the lamp-to-luminaire geometry, then the tilt angles' count
        except (IndexError, ValueError):
            return None
        return words[2 + 2 * max(count, 0):]
    end = rest.find("\n", 1)
    return None if end < 0 else rest[end + 1:].split()


def parse_ies(text: str) -> IesTable | None:
    words = _numbers(text or "")
    if words is None:
        return None
    try:
        head = [float(w) for w in words[:13]]
        if len(head) < 13:
            return None
        factor = head[2] * head[10] * head[11] * CANDELA_TO_WATT
        v_num, h_num, kind = int(head[3]), int(head[4]), int(head[5])
        if kind not in (TYPE_A, TYPE_B, TYPE_C) or v_num <= 0 or h_num <= 0:
            return None
        body = np.array([float(w) for w in words[13:13 + v_num + h_num + v_num * h_num]], np.float64)
    except ValueError:
        return None
    if len(body) < v_num + h_num + v_num * h_num:
        return None
    v = [float(np.float32(a)) for a in body[:v_num]]
    h = [float(np.float32(a)) for a in body[v_num:v_num + h_num]]
    values = (body[v_num + h_num:] * factor).astype(np.float32).reshape(h_num, v_num)
    rows = [values[i] for i in range(h_num)]
    if kind == TYPE_A:
        h, v, rows = _type_a(h, v, rows)
    elif kind == TYPE_B:
        h, v, rows = _type_b(h, v, rows)
    else:
        h, rows = _type_c(h, rows)
    radians = np.float32(np.pi) / np.float32(180.0)
    return IesTable(np.array(h, np.float32) * radians, np.array(v, np.float32) * radians,
                    np.array([np.asarray(r, np.float32) for r in rows], np.float32).reshape(len(h), len(v)))


def _type_a(h, v, rows):
    """Vertical angles shift by 90 degrees; horizontal ones from [-90, 90] map onto [90, 270] reversed, mirrored
    about 0 when the file starts there."""
    v = [a + 90.0 for a in v]
    new_h = [180.0 - h[i] for i in range(len(h) - 1, -1, -1)]
    new_rows = [rows[i] for i in range(len(h) - 1, -1, -1)]
    if _close(h[0], 0.0):
        new_h += [180.0 + h[i] for i in range(1, len(h))]
        new_rows += [rows[i] for i in range(1, len(h))]
    return new_h, v, new_rows


def _type_b(h, v, rows):
    """The polar axis is horizontal: the table is transposed (as Cycles does) and each axis mirrored about 0 when
    it starts there, else shifted by 90 degrees."""
    rows = [np.array([rows[j][i] for j in range(len(h))], np.float32) for i in range(len(v))]
    h, v = v, h
    if _close(h[0], 0.0):
        new_h = [90.0 - h[i] for i in range(len(h) - 1, 0, -1)] + [90.0 + a for a in h]
        rows = [rows[i] for i in range(len(h) - 1, 0, -1)] + list(rows)
        h = new_h
    else:
        h = [a + 90.0 for a in h]
    if _close(v[0], 0.0):
        count = len(v)
        v = [90.0 - v[i] for i in range(count - 1, 0, -1)] + [90.0 + a for a in v]
        rows = [np.concatenate([r[count - 1:0:-1], r]) for r in rows]
    else:
        v = [a + 90.0 for a in v]
    return h, v, rows


def _type_c(h, rows):
    """Horizontal angles rotated from [90, 270] to [0, 180]; one angle made the whole circle; a quadrant or a
    half mirrored to the whole circle; a missing 360-degree column (same spacing as its neighbours) added."""
    h, rows = list(h), list(rows)
    if _close(h[0], 90.0):
        h = [a - 90.0 for a in h]
    if len(h) == 1:
        h = [0.0, 360.0]
        rows = [rows[0], rows[0]]
    if _close(h[-1], 90.0):
        count = len(h)
        for i in range(count - 2, -1, -1):
            h.append(180.0 - h[i])
            rows.append(rows[i])
    if _close(h[-1], 180.0):
        count = len(h)
        for i in range(count - 2, -1, -1):
            h.append(360.0 - h[i])
            rows.append(rows[i])
    if _close(h[0], 0.0) and not _close(h[-1], 360.0) and len(h) >= 2:
        last, first, gap = h[-1] - h[-2], h[1] - h[0], 360.0 - h[-1]
        if _close(last, gap) or _close(first, gap):
            h.append(360.0)
            rows.append(rows[0])
    return h, rows
