#!/usr/bin/env python3
"""Cuts tests/data/ur3e_rad_program.csv out of the RAD artifact's UR3e RTDE recording.

Source: github.com/ubc-systopia/dsn-2022-rad-artifact (MIT, see tests/data/LICENSE-RAD.txt),
`analysis/Dataset_PowerAnalysis/CSV-Files/fig9.xlsx`: one sheet, 888 RTDE rows at 25 Hz
(35.5 s) of a UR3e running a URScript pick-and-place sequence, 174 RTDE outputs per row.
The artifact's `L0L1.csv` … `L4L5.csv` beside it are slices of the same rows.

How it is cut, and nothing else:
- every row is kept, in order (no resampling, no filtering);
- only the columns the dynamics need are kept (KEPT below, in this order); the artifact's
  `_id` column is renamed `wall_clock` (the recorder's wall-clock stamp), RTDE's `timestamp`
  (controller seconds) is kept as is;
- numbers are written with 9 significant digits (the sheet stores RTDE's doubles with 17,
  beyond the controller's own resolution; 9 keeps every joint angle to 1e-8 rad).

Usage: trim_rad_recording.py FIG9_XLSX OUT_CSV   (stdlib only: the sheet is read as XML)
Get the sheet with: git -C <mirror of the artifact> show HEAD:analysis/Dataset_PowerAnalysis/CSV-Files/fig9.xlsx > fig9.xlsx
"""

import csv
import re
import sys
import xml.etree.ElementTree as ET
import zipfile

NS = {"m": "http://schemas.openxmlformats.org/spreadsheetml/2006/main"}
SIX = ["target_q", "target_qd", "target_qdd", "target_current", "target_moment",
       "actual_q", "actual_qd", "actual_current", "joint_temperatures", "joint_mode"]
KEPT = (["wall_clock", "timestamp"]
        + [f"{group}_{k}" for group in SIX for k in range(6)]
        + ["robot_mode", "safety_mode", "runtime_state", "speed_scaling",
           "payload", "payload_cog_0", "payload_cog_1", "payload_cog_2"])


def column_index(reference):
    letters = re.match("[A-Z]+", reference).group()
    index = 0
    for letter in letters:
        index = index * 26 + ord(letter) - 64
    return index - 1


def sheet_rows(path):
    book = zipfile.ZipFile(path)
    strings = [
        "".join(t.text or "" for t in item.iter(f"{{{NS['m']}}}t"))
        for item in ET.fromstring(book.read("xl/sharedStrings.xml")).findall("m:si", NS)
    ]
    sheet = ET.fromstring(book.read("xl/worksheets/sheet1.xml"))
    for row in sheet.iter(f"{{{NS['m']}}}row"):
        cells = {}
        for cell in row.findall("m:c", NS):
            value = cell.find("m:v", NS)
            if value is None:
                continue
            text = value.text
            if cell.get("t") == "s":
                text = strings[int(text)]
            cells[column_index(cell.get("r"))] = text
        if cells:
            yield [cells.get(i, "") for i in range(max(cells) + 1)]


def number(text):
    try:
        return format(float(text), ".9g")
    except ValueError:
        return text


def main(source, target):
    rows = sheet_rows(source)
    header = ["wall_clock" if name == "_id" else name for name in next(rows)]
    where = [header.index(name) for name in KEPT]
    count = 0
    with open(target, "w", newline="") as out:
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(KEPT)
        for row in rows:
            row += [""] * (len(header) - len(row))
            writer.writerow([row[where[0]]] + [number(row[i]) for i in where[1:]])
            count += 1
    print(f"{count} rows, {len(KEPT)} columns -> {target}")


if __name__ == "__main__":
    main(*sys.argv[1:3])
