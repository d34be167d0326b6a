"""Take an agent out: a saved agent's greedy policy as an ONNX graph (:mod:`.onnx_graph`), and a
folder to publish on a model hub with its model card (:mod:`.hub`). ``cartpole export`` runs both."""

from cartpole.export.onnx_graph import (
    EXPORT_EXTRA,
    NEAR_TIE,
    PARITY_OBSERVATIONS,
    ExportError,
    Parity,
    check_parity,
    play_observations,
    require_export_extra,
    write_onnx,
)

__all__ = [
    "EXPORT_EXTRA",
    "NEAR_TIE",
    "PARITY_OBSERVATIONS",
    "ExportError",
    "Parity",
    "check_parity",
    "play_observations",
    "require_export_extra",
    "write_onnx",
]
