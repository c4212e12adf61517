"""A results folder back to its checkpoint, for a resume (``drape run CONFIG --resume``).

``steps.csv`` is rewritten from the checkpoint's records; the XDMF time series (from its copy
``checkpoint.xdmf``, taken with the checkpoint: dolfinx rewrites the XDMF text in place after
every step, and a hard kill at that moment leaves it empty) loses the grids after the
checkpoint's t, and its HDF5 file (from its copy ``checkpoint.h5``: a hard kill during a write
may have left ``fields.h5`` unreadable) is renamed ``fields-<k>.h5`` (the XDMF follows), so
that the resumed run writes into a fresh ``fields.h5`` and never meets a dataset of a step
written after the checkpoint.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

from drape.io.atomic import replace_text

#: a copy of fields.xdmf taken with each checkpoint (dolfinx rewrites the XDMF text in place
#: after every step: a hard kill at that moment leaves it empty)
XDMF_COPY = "checkpoint.xdmf"
#: a copy of fields.h5 taken with each checkpoint: a hard kill while a step's fields are being
#: written can leave the file's group index unreadable, the checkpointed steps' data with it
H5_COPY = "checkpoint.h5"


def rewind_outputs(folder, records: list, t: float, comm) -> None:
    """Collective (rank 0 works): steps.csv is rewritten with ``records`` (the checkpoint's
    drape.step_record.StepRecord);
    fields.xdmf (from the checkpoint's copy) keeps the grids up to ``t``, its fields.h5 (the
    checkpoint's copy where there is one) becomes fields-<k>.h5 (the XDMF follows), and the
    XDMF copy becomes the rewound XDMF, so that a second resume from the same checkpoint finds
    the data where the first one put it."""
    import csv

    from drape.io.writer import FIELDS_FILE, STEPS_FILE, csv_text
    rows = [record.row() for record in records]
    folder = Path(folder)
    if comm.rank == 0:
        text = io.StringIO(newline="")
        writer = csv.writer(text)
        writer.writerow(list(rows[0]))
        for row in rows:
            writer.writerow([csv_text(row.get(name, "")) for name in rows[0]])
        replace_text(folder / STEPS_FILE, text.getvalue())
        xdmf, copy, h5_copy = folder / FIELDS_FILE, folder / XDMF_COPY, folder / H5_COPY
        if copy.is_file():
            replace_text(xdmf, copy.read_text())
        if h5_copy.is_file():
            os.replace(h5_copy, xdmf.with_suffix(".h5"))
        if xdmf.is_file():
            trim_xdmf(xdmf, t)
            replace_text(copy, xdmf.read_text())
    comm.barrier()


def trim_xdmf(path: Path, t: float) -> None:
    """Drop every time-series grid after t; move the HDF5 file aside as <stem>-<k>.h5."""
    import xml.etree.ElementTree as ET
    ET.register_namespace("xi", "http://www.w3.org/2001/XInclude")
    tree = ET.parse(path)
    for collection in tree.getroot().iter("Grid"):
        if collection.get("GridType") != "Collection":
            continue
        for grid in list(collection.findall("Grid")):
            time = grid.find("Time")
            if time is not None and float(time.get("Value")) > t:
                collection.remove(grid)
    h5 = path.with_suffix(".h5")
    if h5.is_file():
        k = 1
        while path.with_name(f"{path.stem}-{k}.h5").exists():
            k += 1
        part = path.with_name(f"{path.stem}-{k}.h5")
        for item in tree.getroot().iter("DataItem"):
            if item.text and item.text.strip().startswith(f"{h5.name}:"):
                item.text = item.text.strip().replace(f"{h5.name}:", f"{part.name}:", 1)
        os.replace(h5, part)
    buffer = io.BytesIO()
    tree.write(buffer, encoding="utf-8", xml_declaration=True)
    replace_text(path, buffer.getvalue().decode())
