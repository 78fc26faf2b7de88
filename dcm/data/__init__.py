"""Datasets: robot-based stiffness search per demo, parallel generation, the HDF5 store and log import.

Only the format module is imported here; generation pulls in the simulator and is imported on demand
(``python -m dcm.data.generate``), so the models can read datasets without MuJoCo.
"""

from dcm.data.schema import (
    CHANNELS,
    FIELDS,
    FORMAT_VERSION,
    DatasetError,
    LoadedDataset,
    load_dataset,
    write_dataset,
)

__all__ = ["CHANNELS", "FIELDS", "FORMAT_VERSION", "DatasetError", "LoadedDataset", "load_dataset", "write_dataset"]
