"""The order a trainer visits its samples in, and the batches it is fed, with or without
DataLoader worker processes.

The adversarial trainer (:mod:`training.adversarial`: the renderer, the baselines) shuffles this
way: a permutation of the data set from a generator seeded by ``seed + 1``, consumed a global
batch at a time, a fresh permutation when the rest is shorter than a batch. :class:`SampleOrder`
is that state and :func:`next_indices` one step of it, a pure function; a checkpoint stores the
order of the last batch *consumed*.

:func:`batches` feeds the trainer. With ``workers == 0`` it loads each batch in the trainer's own
process when asked. With workers, a ``torch.utils.data.DataLoader`` loads them ahead in worker
processes (pinned memory on CUDA): its batch sampler walks the same order, so the batches, and
hence the trained weights, are the same as without workers; each batch comes with the order
after it, which is what the trainer keeps (the sampler itself runs ahead by the prefetched
batches).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class SampleOrder:
    """Where a run is in its shuffled pass over the data set.

    perm : (N,) int64, the current permutation of the sample indices
    pos : index into ``perm`` of the next global batch
    epoch : permutations used up so far
    rng : the shuffling generator's state (``torch.Generator.get_state()``)
    """

    perm: torch.Tensor
    pos: int
    epoch: int
    rng: torch.Tensor

    @staticmethod
    def start(n: int, seed: int) -> SampleOrder:
        """The first permutation of ``n`` samples from a generator seeded by ``seed``."""
        gen = torch.Generator().manual_seed(seed)
        perm = torch.randperm(n, generator=gen)
        return SampleOrder(perm, 0, 0, gen.get_state())


def next_indices(
    order: SampleOrder, batch: int, world: int = 1, rank: int = 0
) -> tuple[list[int], SampleOrder]:
    """This process's sample indices of the next global batch (``batch * world`` samples, this
    rank's slice), and the order after it."""
    g = batch * world
    n = len(order.perm)
    if order.pos + g > n:
        gen = torch.Generator()
        gen.set_state(order.rng)
        perm = torch.randperm(n, generator=gen)
        order = SampleOrder(perm, 0, order.epoch + 1, gen.get_state())
    idx = order.perm[order.pos : order.pos + g].tolist()
    order = SampleOrder(order.perm, order.pos + g, order.epoch, order.rng)
    return idx[rank * batch : (rank + 1) * batch], order


class _Schedule:
    """A DataLoader batch sampler over ``steps`` batches of :func:`next_indices`; the order
    after each batch it yields waits in :attr:`orders` for the trainer to take."""

    def __init__(self, order: SampleOrder, steps: int, batch: int, world: int, rank: int):
        self.order, self.steps = order, steps
        self.batch, self.world, self.rank = batch, world, rank
        self.orders: deque[SampleOrder] = deque()

    def __len__(self) -> int:
        return self.steps

    def __iter__(self) -> Iterator[list[int]]:
        order = self.order
        for _ in range(self.steps):
            idx, order = next_indices(order, self.batch, self.world, self.rank)
            self.orders.append(order)
            yield idx


def for_device(dataset, device):
    """The data set as a trainer on ``device`` loads it: on CUDA, with its motion features per
    vertex when it can give them (``with_motion_per_vertex``; the GPU interpolates them, and the
    batches are several times smaller to make, pass between processes, pin and copy); anywhere
    else, as it is."""
    per_vertex = getattr(dataset, "with_motion_per_vertex", None)
    return per_vertex() if torch.device(device).type == "cuda" and per_vertex else dataset


def batches(
    dataset,
    order: SampleOrder,
    steps: int,
    batch: int,
    collate: Callable[[list], object],
    *,
    workers: int = 0,
    pin_memory: bool = False,
    world: int = 1,
    rank: int = 0,
) -> Iterator[tuple[object, SampleOrder]]:
    """``steps`` batches of ``dataset`` in ``order``: ``(collate(samples), order after it)``.

    ``collate`` turns a list of samples into the trainer's batch (it runs in the worker
    processes when there are any, so it must be a module-level function or a
    ``functools.partial`` of one). Workers are forked from this process and load
    ``2 * workers`` batches ahead.
    """
    if workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    if workers == 0:
        for _ in range(steps):
            idx, order = next_indices(order, batch, world, rank)
            yield collate([dataset[i] for i in idx]), order
        return
    schedule = _Schedule(order, steps, batch, world, rank)
    loader = torch.utils.data.DataLoader(
        dataset,
        batch_sampler=schedule,
        num_workers=workers,
        collate_fn=collate,
        pin_memory=pin_memory,
        multiprocessing_context="fork",
    )
    for item in loader:
        yield item, schedule.orders.popleft()
