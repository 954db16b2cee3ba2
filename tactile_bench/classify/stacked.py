"""Several seeds of one network trained as a single batched network (grouped convolutions).

Training K seeds of a small classifier one after another runs K passes over the data with
K small networks, each too small to keep the hardware busy. :func:`stack_networks` turns the
K networks into one whose layers are K times as wide and grouped, so that seed k only ever
sees seed k's channels: convolutions become grouped convolutions, BatchNorm runs over the K
seeds' channels side by side (its statistics are per channel, so per seed), linear layers
become :class:`GroupedLinear`. Its input is the K seeds' batches concatenated along the
channels, its output the K seeds' logits side by side. Summing the K mean losses gives each
seed's parameters exactly its own gradient, and Adam works elementwise, so one Adam over the
stacked parameters takes the K separate steps: each seed ends where training it alone would,
up to the order floating-point sums run in. :func:`unstack_network` gives the K back.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator, Sequence
from itertools import islice
from typing import Any

import lightning as L
import torch
from torch import nn
from torch.nn import functional as F

from tactile_bench.classify.module import random_shift
from tactile_bench.training import ResumableSampler

#: parameter-free layers that mix channels (or draw random numbers): a stacked network with
#: one would mix seeds (or draw another sequence than each seed alone)
_MIXING = (nn.Softmax, nn.LogSoftmax, nn.ChannelShuffle, nn.LocalResponseNorm, nn.GroupNorm)
_MIXING += (nn.LayerNorm, nn.modules.dropout._DropoutNd)


class GroupedLinear(nn.Module):
    """K independent linear layers on inputs (N, K * in), outputs (N, K * out): block k of
    the output is layer k of block k of the input (one einsum for the K)."""

    def __init__(self, weight: torch.Tensor, bias: torch.Tensor | None) -> None:
        super().__init__()
        self.weight = nn.Parameter(weight)  # (K, out, in)
        self.bias = nn.Parameter(bias) if bias is not None else None  # (K, out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        count, _, width = self.weight.shape
        out = torch.einsum("nki,koi->nko", x.reshape(len(x), count, width), self.weight)
        if self.bias is not None:
            out = out + self.bias
        return out.reshape(len(x), -1)


def _own_tensors(module: nn.Module) -> dict[str, torch.Tensor]:
    """The parameters and buffers ``module`` holds itself (not its children's)."""
    own = dict(module.named_parameters(recurse=False))
    own.update(module.named_buffers(recurse=False))
    return {k: v for k, v in own.items() if v is not None}


def _layout(net: nn.Module) -> list[Any]:
    """Each module's name, type and own tensors' shapes: equal for networks that stack."""
    own = [(name, m, _own_tensors(m)) for name, m in net.named_modules()]
    return [(name, type(m), {k: v.shape for k, v in t.items()}) for name, m, t in own]


def _stack_conv(convs: Sequence[nn.Conv2d]) -> nn.Conv2d:
    c, k = convs[0], len(convs)
    stacked = nn.utils.skip_init(  # no initialisation: the global RNG is left as it was
        nn.Conv2d,
        k * c.in_channels,
        k * c.out_channels,
        c.kernel_size,
        stride=c.stride,
        padding=c.padding,
        dilation=c.dilation,
        groups=k * c.groups,
        bias=c.bias is not None,
        padding_mode=c.padding_mode,
        device=c.weight.device,
        dtype=c.weight.dtype,
    )
    with torch.no_grad():
        stacked.weight.copy_(torch.cat([m.weight for m in convs]))
        if c.bias is not None:
            stacked.bias.copy_(torch.cat([m.bias for m in convs]))
    return stacked


def _stack_norm(norms: Sequence[nn.BatchNorm2d]) -> nn.BatchNorm2d:
    n = norms[0]
    counts = {int(m.num_batches_tracked) for m in norms if m.num_batches_tracked is not None}
    if len(counts) > 1:  # one counter for the K: unstacking could not give each its own back
        raise ValueError("stack_networks: BatchNorm num_batches_tracked differ between seeds")
    stacked = nn.BatchNorm2d(
        len(norms) * n.num_features,
        eps=n.eps,
        momentum=n.momentum,
        affine=n.affine,
        track_running_stats=n.track_running_stats,
    )
    floats = [t for t in _own_tensors(n).values() if t.is_floating_point()]
    if floats:
        stacked.to(device=floats[0].device, dtype=floats[0].dtype)
    with torch.no_grad():
        for name, tensor in _own_tensors(stacked).items():
            parts = [getattr(m, name) for m in norms]
            tensor.copy_(parts[0] if tensor.ndim == 0 else torch.cat(parts))
    return stacked


def _stack_linear(linears: Sequence[nn.Linear]) -> GroupedLinear:
    bias = None
    if linears[0].bias is not None:
        bias = torch.stack([m.bias.detach() for m in linears]).clone()
    return GroupedLinear(torch.stack([m.weight.detach() for m in linears]).clone(), bias)


def stack_networks(nets: Sequence[nn.Module]) -> nn.Module:
    """One network computing the K = len(nets) networks side by side on inputs
    (B, K * C, ...), seed k's in channel block k, to outputs (B, K * out) (see module doc).

    Raises ValueError for nets of different structures and for any layer other than
    Conv2d, BatchNorm2d and Linear that holds parameters or buffers (or mixes channels):
    those seeds are to be trained one at a time.
    """
    if not nets:
        raise ValueError("stack_networks: no networks")
    for i, net in enumerate(nets[1:], start=1):
        if _layout(net) != _layout(nets[0]):
            raise ValueError(f"stack_networks: network {i} differs in structure from network 0")
    stacked = copy.deepcopy(nets[0])
    modules = [dict(net.named_modules()) for net in nets]
    for name, module in list(stacked.named_modules()):
        parts = [m[name] for m in modules]
        kind = type(module)
        if kind is nn.Conv2d:
            new: nn.Module = _stack_conv(parts)
        elif kind is nn.BatchNorm2d:
            new = _stack_norm(parts)
        elif kind is nn.Linear:
            new = _stack_linear(parts)
        elif _own_tensors(module) or isinstance(module, _MIXING):
            raise ValueError(f"stack_networks: cannot stack {name or 'the net'} ({kind.__name__})")
        else:
            continue
        new.train(module.training)
        if not name:  # the network is a single layer
            return new
        stacked.set_submodule(name, new)
    return stacked


def unstack_network(stacked: nn.Module, template: nn.Module, count: int) -> list[nn.Module]:
    """The ``count`` networks :func:`stack_networks` stacked: copies of ``template`` holding
    each seed's slice of every parameter and buffer of ``stacked``."""
    nets = [copy.deepcopy(template) for _ in range(count)]
    inner = dict(stacked.named_modules())
    with torch.no_grad():
        for name, module in template.named_modules():
            for key, tensor in _own_tensors(module).items():
                whole = getattr(inner[name], key)
                for k, net in enumerate(nets):
                    getattr(net.get_submodule(name), key).copy_(_slice(whole, k, count, tensor))
    return nets


def _slice(whole: torch.Tensor, k: int, count: int, like: torch.Tensor) -> torch.Tensor:
    """Seed k's part of a stacked tensor shaped as ``like``: a shared counter, a row of a
    GroupedLinear tensor, or block k along dimension 0."""
    if whole.ndim == 0:
        part = whole
    else:
        part = whole[k] if whole.ndim == like.ndim + 1 else whole.chunk(count)[k]
    if part.shape != like.shape:
        raise ValueError(f"unstack_network: {tuple(whole.shape)} does not split into {count}")
    return part


class StackedClassifier(L.LightningModule):
    """Trains a stacked network (``stack_networks``) of ``count`` classifiers: batches are
    (x (B, count * C, S, S), y (count, B)), the loss the sum of the seeds' mean losses."""

    def __init__(
        self,
        net: nn.Module,
        count: int,
        num_classes: int,
        lr: float,
        weight_decay: float = 0.0,
        shift_px: int = 0,
    ) -> None:
        super().__init__()
        self.net = net
        self.count = count
        self.num_classes = num_classes
        self.lr = lr
        self.weight_decay = weight_decay
        # random shifts (BrailleClassifier's augmentation) of each stacked image, the same for
        # every member: what each draws alone when the members share one seed
        self.shift_px = shift_px

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (B, count, num_classes) for the seeds' stacked batches (B, count * C, S, S)."""
        return self.net(x).view(len(x), self.count, self.num_classes)

    def training_step(
        self, batch: tuple[torch.Tensor, torch.Tensor], batch_idx: int
    ) -> torch.Tensor:
        x, y = batch
        if self.shift_px > 0:
            x = random_shift(x, self.shift_px)
        logits = self(x)
        # a sum: each seed's parameters get exactly the gradient of its own mean loss
        loss = torch.stack([F.cross_entropy(logits[:, k], y[k]) for k in range(self.count)]).sum()
        mean = loss.detach() / self.count
        self.log(
            "train_loss",
            mean,
            prog_bar=True,
            on_step=True,
            on_epoch=True,
            sync_dist=True,
            batch_size=len(x),
        )
        return loss

    def configure_optimizers(self) -> torch.optim.Optimizer:
        # Adam is elementwise: one over the stacked parameters is the seeds' own Adams
        return torch.optim.Adam(self.parameters(), lr=self.lr, weight_decay=self.weight_decay)


class SamplerGroup:
    """The K seeds' ``ResumableSampler``s behind the one interface ``GuardedCheckpoint``
    saves and restores a data position through (their states stacked)."""

    def __init__(self, samplers: Sequence[ResumableSampler]) -> None:
        self.samplers = list(samplers)

    @property
    def epoch_state(self) -> torch.Tensor | None:
        states = [s.epoch_state for s in self.samplers]
        if any(state is None for state in states):
            return None  # an epoch not begun yet
        return torch.stack([state for state in states if state is not None])

    def next_epoch_state(self) -> torch.Tensor:
        return torch.stack([s.next_epoch_state() for s in self.samplers])

    def resume(self, epoch_state: torch.Tensor, batches_done: int) -> None:
        for sampler, state in zip(self.samplers, epoch_state, strict=True):
            sampler.resume(state.clone(), batches_done)  # a view: set_state would crash

    @property
    def shard(self) -> tuple[int, int]:
        return self.samplers[0].shard

    @shard.setter
    def shard(self, value: tuple[int, int]) -> None:
        for sampler in self.samplers:
            sampler.shard = value

    def __len__(self) -> int:
        return len(self.samplers[0])


class SeedBatches:
    """Each seed's batches of ``(x, y)``, as ``DataLoader(TensorDataset(x, y), batch_size,
    sampler=ResumableSampler(n, g, batch_size), generator=g)`` with ``g`` seeded by the seed
    gives them (``DeviceBatches``' way), stacked: (x batches concatenated along dim 1, y
    batches stacked (K, B)). ``subsets``: each seed trains on its own rows of ``tensors``
    (its training split), as if they were its ``TensorDataset``; all of one length. The
    tensors (and subsets) may be replaced by copies on another device (``to``)."""

    def __init__(
        self,
        tensors: tuple[torch.Tensor, torch.Tensor],
        seeds: Sequence[int],
        batch_size: int,
        subsets: Sequence[torch.Tensor] | None = None,
    ) -> None:
        self.tensors = tensors
        self.batch_size = batch_size
        self.generators = [torch.Generator().manual_seed(int(s)) for s in seeds]
        n = len(tensors[0])
        rows = [torch.arange(n)] * len(seeds) if subsets is None else list(subsets)
        if len(rows) != len(seeds) or len({len(r) for r in rows}) != 1:
            raise ValueError(f"SeedBatches: {len(seeds)} seeds need subsets of one length")
        self.subsets = torch.stack([r.long() for r in rows])  # (K, n): seed k's rows
        per_seed = self.subsets.shape[1]
        self.sampler = SamplerGroup(
            [ResumableSampler(per_seed, g, batch_size) for g in self.generators]
        )

    def to(self, device: torch.device) -> None:
        """Move the tensors and subsets to ``device`` (once: batches are drawn there)."""
        self.tensors = (self.tensors[0].to(device), self.tensors[1].to(device))
        self.subsets = self.subsets.to(device)

    def __len__(self) -> int:
        return -(-len(self.sampler) // self.batch_size)

    def __iter__(self) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        for generator in self.generators:  # each loader's base seed, as a DataLoader draws it
            torch.empty((), dtype=torch.int64).random_(generator=generator)
        x, y = self.tensors
        orders = [iter(s) for s in self.sampler.samplers]
        while True:
            batches = [list(islice(order, self.batch_size)) for order in orders]
            if not batches[0]:
                return
            positions = torch.tensor(batches, dtype=torch.long, device=x.device)  # (K, B)
            index = self.subsets.gather(1, positions)
            yield torch.cat([x[i] for i in index], dim=1), y[index]


class SeedDataModule(L.LightningDataModule):
    """Serves ``batches`` with its tensors moved once to the device the fit runs on."""

    def __init__(self, batches: SeedBatches) -> None:
        super().__init__()
        self.batches = batches

    def train_dataloader(self) -> SeedBatches:
        trainer = self.trainer
        device = trainer.strategy.root_device if trainer is not None else torch.device("cpu")
        if self.batches.tensors[0].device != device:
            self.batches.to(device)
        return self.batches
