"""``[simulation]`` tables of session files: what ``shipstar demo`` simulates.

Read by ``shipstar demo`` only: the simulated ship motion, star magnitude limit, noise
seed, which frames are rendered as images.
"""

from __future__ import annotations

from dataclasses import dataclass

from shipstar.config._toml import _Table


@dataclass(frozen=True)
class MotionConfig:
    """Simulated ship motion (see :class:`shipstar.simulate._session.ShipMotion`); angles in degrees."""

    heading_deg: float
    heading_rate_deg_per_s: float = 0.0
    yaw_amplitude_deg: float = 0.0
    yaw_period_s: float = 12.0
    pitch_deg: float = 0.0
    pitch_amplitude_deg: float = 0.0
    pitch_period_s: float = 6.0
    pitch_phase_deg: float = 0.0
    roll_deg: float = 0.0
    roll_amplitude_deg: float = 0.0
    roll_period_s: float = 8.0
    roll_phase_deg: float = 0.0
    speed_m_per_s: float = 0.0


@dataclass(frozen=True)
class SimulationConfig:
    """What ``shipstar demo`` simulates for a session.

    Attributes
    ----------
    true_refraction_model : str
        The atmosphere of the simulation (``"erfa"``: within 0.03'' of ray tracing).
    mag_limit : float
        Faintest Hp magnitude simulated.
    centroid_sigma_px : float
        Centroid noise of centroid-level frames (image-level frames get theirs from
        the rendered image).
    seed : int
    image_level_s : float
        Frames before this time (s since the start) are rendered and extracted; the
        rest are centroid level.
    exposure_s : float or None
        Replaces the cameras' exposure time for rendered frames (None: keep it).  At sea
        the deck turns by up to 4 deg/s, which smears an 80 ms exposure over 25-40 px.
    motion : MotionConfig or None
        Sea sessions; dock sessions hold still at the ``[dock]`` attitude.
    """

    true_refraction_model: str = "erfa"
    mag_limit: float = 8.0
    centroid_sigma_px: float = 0.1
    seed: int = 0
    image_level_s: float = 0.0
    exposure_s: float | None = None
    motion: MotionConfig | None = None


def _motion(t: _Table | None) -> MotionConfig | None:
    if t is None:
        return None
    ang = dict(lo=-360.0, hi=360.0)
    per = dict(lo=0.0, hi=3600.0, lo_open=True)
    m = MotionConfig(
        heading_deg=t.number("heading_deg", **ang), heading_rate_deg_per_s=t.number("heading_rate_deg_per_s", 0.0,
                                                                                     lo=-10.0, hi=10.0),
        yaw_amplitude_deg=t.number("yaw_amplitude_deg", 0.0, lo=0.0, hi=45.0), yaw_period_s=t.number("yaw_period_s",
                                                                                                      12.0, **per),
        pitch_deg=t.number("pitch_deg", 0.0, limit="pitch_deg"),
        pitch_amplitude_deg=t.number("pitch_amplitude_deg", 0.0, lo=0.0, hi=30.0),
        pitch_period_s=t.number("pitch_period_s", 6.0, **per), pitch_phase_deg=t.number("pitch_phase_deg", 0.0, **ang),
        roll_deg=t.number("roll_deg", 0.0, limit="roll_deg"),
        roll_amplitude_deg=t.number("roll_amplitude_deg", 0.0, lo=0.0, hi=45.0),
        roll_period_s=t.number("roll_period_s", 8.0, **per), roll_phase_deg=t.number("roll_phase_deg", 0.0, **ang),
        speed_m_per_s=t.number("speed_m_per_s", 0.0, limit="speed_m_per_s"))
    t.finish()
    return m


def _simulation(t: _Table | None) -> SimulationConfig:
    from shipstar.sky.refraction import MODELS

    if t is None:
        return SimulationConfig()
    sim = SimulationConfig(
        true_refraction_model=t.text("true_refraction_model", "erfa", choices=MODELS),
        mag_limit=t.number("mag_limit", 8.0, lo=0.0, hi=12.0), centroid_sigma_px=t.number("centroid_sigma_px", 0.1,
                                                                                           lo=0.0, hi=10.0),
        seed=t.integer("seed", 0), image_level_s=t.number("image_level_s", 0.0, lo=0.0),
        exposure_s=t.number("exposure_s", None, lo=0.0, hi=10.0, lo_open=True), motion=_motion(t.table("ship_motion")))
    t.finish()
    return sim
