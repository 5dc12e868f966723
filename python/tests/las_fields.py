"""What the pytest suites share: the environment `cargo test --test python`
gives them, and pcimg's fields with laspy's dimension for each."""

import os

import pytest

# pcimg's fields that come back exactly, and laspy's dimension for each.
EXACT = {
    "Intensity": "intensity",
    "ReturnNumber": "return_number",
    "NumberOfReturns": "number_of_returns",
    "Classification": "classification",
    "Red": "red",
    "Green": "green",
    "Blue": "blue",
    "ScanAngleRank": "scan_angle_rank",
    "UserData": "user_data",
    "PointSourceId": "point_source_id",
    "ScanDirectionFlag": "scan_direction_flag",
    "EdgeOfFlightLine": "edge_of_flight_line",
}


def given(*names):
    """The environment variables `names`; the module is skipped when one is
    missing (run outside `cargo test --test python`, which makes the data)."""
    values = [os.environ.get(n) for n in names]
    if not all(values):
        pytest.skip(
            "run through `cargo test --test python` (it makes the test dataset)",
            allow_module_level=True,
        )
    return values
