"""The volume stack: the media a path is inside, changed where its rays cross a surface whose material has a
Volume output (Cycles' volume_stack_enter_exit, kernel/integrator/volume_stack.h): a ray that meets the
surface from the front enters the medium behind it, from behind leaves it. A medium is on a stack once; a
full stack takes no more (as Cycles')."""
from __future__ import annotations

import numpy as np


def enter_exit(stack: np.ndarray, medium: np.ndarray, leaving: np.ndarray) -> np.ndarray:
    """The stacks (K, n) after the rays cross into (or, leaving, out of) media (n,) (-1: no medium there)."""
    rows = np.flatnonzero(medium >= 0)
    if not len(rows):
        return stack
    stack = stack.copy()
    m = medium[rows]
    part = stack[:, rows]
    present = part == m[None]
    out = leaving[rows]
    part[:, out] = np.where(present[:, out], -1, part[:, out])
    enter = np.flatnonzero(~out & ~present.any(axis=0))
    if len(enter):
        empty = part[:, enter] < 0
        slot = np.argmax(empty, axis=0)
        room = empty.any(axis=0)
        part[slot[room], enter[room]] = m[enter[room]]
    stack[:, rows] = part
    return stack


def last_objects(media, stacks: np.ndarray) -> np.ndarray:
    """(n,) object rows of the last medium on each stack (K, n) of medium ids (media: medium.Media), -1 for the
    world's fog and for points in no medium: the object Cycles gives a volume point, that of the last stack
    entry it evaluates (kernel/integrator/volume_shader.h volume_shader_eval_entry), whose light group, light
    set and light linking its emission and light samples take."""
    filled = stacks >= 0
    last = np.where(filled.any(axis=0), stacks.shape[0] - 1 - np.argmax(filled[::-1], axis=0), 0)
    medium = stacks[last, np.arange(stacks.shape[1])]
    return np.where(medium >= 0, np.take(media.object, np.maximum(medium, 0)), -1)
