"""``site.toml``: the dock or start position (geodetic, deflection of the vertical)."""

from __future__ import annotations

from dataclasses import dataclass

from shipstar.config._toml import _read_toml
from shipstar.errors import ShipstarError


@dataclass(frozen=True)
class SiteConfig:
    """A dock or start position: geodetic (WGS84) and the deflection of the vertical."""

    name: str
    lat_deg: float
    lon_deg: float
    height_m: float = 0.0
    xi_arcsec: float = 0.0
    eta_arcsec: float = 0.0

    def site(self):
        """The :class:`shipstar.sky.apparent.Site` (validated there too)."""
        from shipstar.sky.apparent import Site

        return Site.from_deg(self.lat_deg, self.lon_deg, self.height_m, self.xi_arcsec, self.eta_arcsec)


def load_site(path) -> SiteConfig:
    """Read a ``site.toml`` (format ``shipstar-site``)."""
    path, t = _read_toml(path, "site")
    s = t.table("site", required=True)
    cfg = SiteConfig(name=s.text("name", ""), lat_deg=s.number("lat_deg", limit="lat_deg"),
                     lon_deg=s.number("lon_deg", limit="lon_deg"), height_m=s.number("height_m", 0.0),
                     xi_arcsec=s.number("xi_arcsec", 0.0), eta_arcsec=s.number("eta_arcsec", 0.0))
    s.finish()
    t.finish()
    try:
        cfg.site()
    except ShipstarError as exc:
        raise ShipstarError(f"{path}: {exc}") from None
    return cfg
