"""shipstar: ship heading, pitch and roll to arcseconds from star sensor images.

``import shipstar`` is cheap: it loads no catalog and no plotting library.  The public
API is what ``__all__`` lists; sub-modules with a leading underscore are private.
"""

from __future__ import annotations

__version__ = "0.1.0"

from shipstar.errors import AccuracyWarning, ShipstarError
from shipstar.frames import (
    C_deck_from_sensor,
    C_hor_from_deck,
    C_icrs_from_sensor,
    az_el_from_unit,
    installation_angles_from_C_deck_from_sensor,
    matrix_from_q_wxyz,
    q_wxyz_from_matrix,
    ra_dec_from_unit,
    ra_dec_roll_from_C_icrs_from_sensor,
    ship_angles_from_C_hor_from_deck,
    unit_from_az_el,
    unit_from_ra_dec,
)

__all__ = [
    "__version__",
    "ShipstarError",
    "AccuracyWarning",
    "C_hor_from_deck",
    "C_deck_from_sensor",
    "C_icrs_from_sensor",
    "ship_angles_from_C_hor_from_deck",
    "installation_angles_from_C_deck_from_sensor",
    "ra_dec_roll_from_C_icrs_from_sensor",
    "unit_from_az_el",
    "az_el_from_unit",
    "unit_from_ra_dec",
    "ra_dec_from_unit",
    "q_wxyz_from_matrix",
    "matrix_from_q_wxyz",
]
