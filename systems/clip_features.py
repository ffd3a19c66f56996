"""ClipFeatures: the information vector z(t) of each camera frame (paper eq. 4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, Context, LeafSystem
from pydrake.systems.sensors import ImageRgba8U

from pcvfe_drake.perception.features import (
    DESCRIPTOR_BACKEND,
    LAMBDA_C,
    BlankImageError,
    FeatureExtractor,
    make_extractor,
)


class ClipFeatures(LeafSystem):
    """Computes z = concat(z_s, lambda_c * mean RGB) of the camera image.

    .. pydrake_system::

        name: ClipFeatures
        input_ports:
        - image
        output_ports:
        - features

    Ports:
        image: input, abstract ``ImageRgba8U`` (any size; alpha ignored), e.g. from
            ``TextureCamera``.
        features: output vector (``extractor.dim``): 36 numbers for CLIP with the paper's 33
            captions, 23 for the descriptor backend (names in :attr:`feature_names`). Computed
            in the output calculation, so Drake's cache recomputes it only when the image
            changes (its only prerequisite); with a camera at 10 Hz that is once per frame.
            An all-black frame (camera failure) gives NaN features, which the clustering marks
            as noise; any other bad image raises ``ValueError``.

    No state, no events: the rate is the camera's.

    Args:
        backend: ``"descriptor"`` (default), the path of a CLIP model folder, or a
            :class:`pcvfe_drake.perception.features.FeatureExtractor`.
        lambda_c: weight of the mean RGB (paper: 0.25); ignored for an extractor instance.
        threads: onnxruntime intra-op threads of the CLIP backend (1 is the safer choice on a
            loaded 2-core machine); ignored for the descriptor and for an extractor instance.
    """

    def __init__(
        self,
        backend: str | Path | FeatureExtractor = DESCRIPTOR_BACKEND,
        lambda_c: float = LAMBDA_C,
        threads: int = 2,
    ) -> None:
        super().__init__()
        if isinstance(backend, FeatureExtractor):
            self._extractor = backend
        elif str(backend) == DESCRIPTOR_BACKEND:
            self._extractor = make_extractor(DESCRIPTOR_BACKEND, lambda_c=lambda_c)
        else:
            self._extractor = make_extractor(
                "clip", clip_dir=backend, lambda_c=lambda_c, threads=threads
            )
        self._image_port = self.DeclareAbstractInputPort(
            "image", AbstractValue.Make(ImageRgba8U(224, 224))
        )
        self._features_port = self.DeclareVectorOutputPort(
            "features",
            self._extractor.dim,
            self._calc_features,
            prerequisites_of_calc={self.input_port_ticket(self._image_port.get_index())},
        )

    @property
    def extractor(self) -> FeatureExtractor:
        return self._extractor

    @property
    def feature_names(self) -> list[str]:
        """Names of the components of ``features``."""
        return self._extractor.names

    def _calc_features(self, context: Context, output: BasicVector) -> None:
        image = self._image_port.Eval(context)
        try:  # RGBA: the extractor takes its RGB in one contiguous copy
            z = self._extractor.extract_one(np.asarray(image.data))
        except BlankImageError:
            z = np.full(self._extractor.dim, np.nan)
        except ValueError as exc:
            raise ValueError(f"ClipFeatures: input 'image' at t = {context.get_time():.3f} s: "
                             f"{exc}") from exc  # fmt: skip
        output.SetFromVector(z)
