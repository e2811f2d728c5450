"""The scene object every loader returns and the trainer consumes."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import overload

import torch
from torch import Tensor

from splatu.camera import Camera


class ViewList:
    """One tensor per view, of differing shapes: a split whose images differ in size (nerfstudio's per-frame `w`, `h`,
    several COLMAP cameras). Indexed as the stacked tensor of a split of one size is, so consumers that go view by view
    take either: `[i]` is view i's tensor, `[indices]` the views at those indices, iteration goes view by view."""

    def __init__(self, items: Sequence[Tensor]) -> None:
        self._items = list(items)

    def __len__(self) -> int:
        return len(self._items)

    def __iter__(self) -> Iterator[Tensor]:
        return iter(self._items)

    @overload
    def __getitem__(self, index: int) -> Tensor: ...

    @overload
    def __getitem__(self, index: Tensor) -> PerView: ...

    def __getitem__(self, index: int | Tensor) -> PerView:
        if isinstance(index, Tensor):
            return per_view([self._items[i] for i in index.tolist()])
        return self._items[index]


PerView = Tensor | ViewList
"""A split's per-view tensors: stacked, (N, H, W, ...), when its views share one size (the common case, which keeps
whole-split operations batched), else a `ViewList`."""


def per_view(items: Sequence[Tensor]) -> PerView:
    """`items` stacked when they share one shape, else a `ViewList` of them. One tensor is not copied: a view of a
    `ViewList` taken alone (`TrainImages` downsamples them so) shares its pixels, as a split of one size's do."""
    if len(items) == 1:
        return items[0].unsqueeze(0)
    return torch.stack(list(items)) if all(t.shape == items[0].shape for t in items) else ViewList(items)


@dataclass
class Views:
    """One split: cameras with their images, each at its own camera's size.

    images are float32 in [0, 1], (H, W, 3) per view, stacked to (N, H, W, 3) when the views share one size (a
    `ViewList` when they do not: `PerView`); every optional tensor is held alike, per image:
    `object_masks` marks the pixels that show the object, which AUSE scores (the images' alpha times the
    scene's mask files, `mask_files`, which training and PSNR use); `alphas` is the images' own alpha when
    they had one (RGBA files; 1 for the split's opaque images), with `images` composited on
    `alpha_background`, so `on_background` can put them on any other colour; `depths` and
    `observed` exist only where ground truth is known (the built-in scene): `observed` marks
    pixels whose surface point is seen, unoccluded, by at least one training camera.
    """

    cameras: list[Camera]
    images: PerView
    names: list[str]
    object_masks: PerView | None = None
    depths: PerView | None = None
    observed: PerView | None = None
    alphas: PerView | None = None
    alpha_background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    mask_files: PerView | None = None
    """The scene's mask files alone (nerfstudio `mask_path`), (H, W) per view in [0, 1]: 0 marks a pixel that
    training and scoring ignore. `object_masks` is this times the images' alpha."""

    def __len__(self) -> int:
        return len(self.cameras)

    def target(self, index: int, background: Tensor) -> Tensor:
        """Image `index` (H, W, 3) as a render on `background` should reproduce it: recomposited there when the
        image had its own alpha, as it is otherwise."""
        image = self.images[index]
        return image if self.alphas is None else on_background(image, self.alphas[index], self.alpha_background,
                                                                background)

    def subset(self, indices: list[int]) -> Views:
        """The views at `indices`, in that order, with every per-image tensor sliced alike."""
        index = torch.as_tensor(indices, dtype=torch.long)

        def pick(t: PerView | None) -> PerView | None:
            return None if t is None else t[index]

        return Views([self.cameras[i] for i in indices], self.images[index], [self.names[i] for i in indices],
                     pick(self.object_masks), pick(self.depths), pick(self.observed), pick(self.alphas),
                     self.alpha_background, pick(self.mask_files))


def on_background(images: Tensor, alphas: Tensor, composited_on: tuple[float, float, float] | Tensor,
                  background: Tensor) -> Tensor:
    """Images (..., H, W, 3) composited on `composited_on`, recomposited on `background`.

    C = rgb·α + b·(1 − α) is linear in b, so C + (b' − b)(1 − α) = rgb·α + b'·(1 − α) exactly, and that
    survives area downsampling (linear too) as long as α is downsampled the same way.
    """
    shift = background.to(images) - torch.as_tensor(composited_on).to(images)
    return images + (1.0 - alphas).unsqueeze(-1) * shift


@dataclass
class Scene:
    """Train and eval views in normalised world coordinates, plus initial points.

    `eval` is the primary held-out split (for the built-in scene: the contiguous block that
    makes an unseen angle).

    World coordinates were normalised as x_norm = (x_orig - center) * scale (nerfstudio
    style); `center` and `scale` record that so exports can be mapped back.
    """

    name: str
    source: str
    train: Views
    eval: Views
    points: Tensor  # (M, 3), may be empty
    point_colors: Tensor | None = None  # (M, 3) in [0, 1]
    center: Tensor = field(default_factory=lambda: torch.zeros(3, dtype=torch.float64))
    scale: float = 1.0
    extra_eval: dict[str, Views] = field(default_factory=dict)
    """More held-out sets, e.g. "interp": every 8th frame of the training path (built-in scene)."""
    own_split: bool = False
    """Whether the split is the scene file's own lists (not one made by --eval-split)."""
    stand_in: bool = False
    """Whether this is the built-in poster stand-in, not a real capture: `train` says so in its scene line, and its
    summary.json and eval-ause's report record it, so its numbers are not read as the real poster's."""


@dataclass(frozen=True)
class CameraViews:
    """A split's cameras and names, without its images: where the training views looked from, not what they show.
    `mask_files` as in `Views`, decoded only when asked (the methods that count what training views see honour it)."""

    cameras: list[Camera]
    names: list[str]
    mask_files: PerView | None = None


@dataclass(frozen=True)
class CameraScene:
    """A `Scene` without its pixels: its normalisation (`center`, `scale`) and its training split's cameras. Enough to
    place cameras given in the data's frame, orbit the capture, name a view's nearest training view, and build the
    methods that look at where the training views were (visibility, fisher, angle), so those renders decode no
    image: decoding fox's photos took longer than rendering four candidate views of it (docs/results.md)."""

    center: Tensor
    scale: float
    train: CameraViews
