"""The effective rig of a command: which driver, address, baud rate and camera it opens (one rule for all).

Rule (docs/user-guide.md, "One rig per campaign"): every command that drives a
rig takes each of ``driver``, ``port``, ``host``, ``baud`` and ``camera`` from,
in this order, the explicit command-line option, the campaign's
``campaign.toml [rig]``, then the documented default (:data:`DEFAULTS`). A
campaign is one rig: a command that would record into a campaign with another
driver than its ``[rig] driver`` is refused (:func:`check_campaign_rig`), and
so is a hand-eye record made on another driver (:func:`check_record_rig`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fgcd_cli.app.scenario import SimScenario, check_connection, check_driver
from fgcd_cli.errors import CampaignError, UserInputError
from fgcd_drivers.connect import Driver

__all__ = [
    "DEFAULT_BAUD",
    "DEFAULT_CAMERA",
    "DEFAULT_DRIVER",
    "DEFAULT_SCENE",
    "EffectiveRig",
    "RigOptions",
    "calibration_campaign",
    "campaign_rig_section",
    "check_campaign_rig",
    "check_record_rig",
    "parse_camera",
    "resolve_rig",
]

DEFAULT_DRIVER = Driver.SIM.value
#: GRBL 1.1's factory baud rate.
DEFAULT_BAUD = 115200
#: The first camera OpenCV enumerates.
DEFAULT_CAMERA = 0
#: The simulator's scene when neither ``--scene`` nor a campaign's ``[rig.sim] scene`` names one (the world's default).
DEFAULT_SCENE = SimScenario.scene


@dataclass(frozen=True, kw_only=True)
class RigOptions:
    """The rig options as given on the command line (None: not given).

    Attributes
    ----------
    driver : str or None
        ``--driver``: sim, grbl, ur or manual.
    port, host : str or None
        ``--port`` (GRBL serial device), ``--host`` (UR controller address).
    baud : int or None
        ``--baud`` (GRBL).
    camera : str or None
        ``--camera``: an OpenCV index (``0``) or a device path (``/dev/video2``).
    """

    driver: str | None = None
    port: str | None = None
    host: str | None = None
    baud: int | None = None
    camera: str | None = None


@dataclass(frozen=True, kw_only=True)
class EffectiveRig:
    """The rig a command opens, each value resolved by the one rule (option > campaign.toml [rig] > default).

    Attributes
    ----------
    driver : str
    port, host : str or None
    baud : int
    camera : int or str
        OpenCV camera index, or a device path.
    driver_given : bool
        ``--driver`` was on the command line.
    """

    driver: str
    port: str | None = None
    host: str | None = None
    baud: int = DEFAULT_BAUD
    camera: int | str = DEFAULT_CAMERA
    driver_given: bool = False

    def record(self) -> dict:
        """What a rig record says about the rig that made it: the driver and its address (JSON)."""
        rec: dict = {"driver": self.driver}
        if self.driver == Driver.GRBL:
            rec.update(port=self.port, baud=self.baud)
        elif self.driver == Driver.UR:
            rec["host"] = self.host
        if self.driver != Driver.SIM:
            rec["camera"] = self.camera
        return rec


def parse_camera(value, *, where: str = "--camera") -> int | str:
    """An OpenCV camera: ``"2"`` -> 2 (an index), a device path stays text; UserInputError when empty or negative."""
    if isinstance(value, bool) or value is None:
        raise UserInputError(f"{where} must be a camera index (0, 1...) or a device path (/dev/video2)")
    if isinstance(value, int):
        index = value
    else:
        text = str(value).strip()
        if not text:
            raise UserInputError(f"{where} must be a camera index (0, 1...) or a device path (/dev/video2)")
        if not text.lstrip("-").isdigit():
            return text
        index = int(text)
    if index < 0:
        raise UserInputError(f"{where} must be a camera index >= 0 or a device path, got {index}")
    return index


def _check_baud(value, *, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise UserInputError(f"{where} must be a positive whole number of bits per second (e.g. 115200), got {value!r}")
    return value


def _config(campaign) -> dict:
    return campaign.rig_config if campaign is not None else {}


def resolve_rig(campaign, given: RigOptions) -> EffectiveRig:
    """The effective rig of a command: each value from the option, else campaign.toml [rig], else the default.

    Checked before anything is opened: the driver's name, the address it needs
    (UserInputError naming the option, exit 2), the baud rate and the camera.
    A malformed value in campaign.toml [rig] is a campaign problem (CampaignError, exit 3).
    ``campaign`` may be None (a command run without ``-c``).
    """
    config = _config(campaign)
    if given.driver is not None:
        check_driver(given.driver)
    try:
        stored_baud = _check_baud(config.get("baud", DEFAULT_BAUD), where="campaign.toml [rig] baud")
        stored_camera = parse_camera(config.get("camera", DEFAULT_CAMERA), where="campaign.toml [rig] camera")
        stored_driver = check_driver(str(config.get("driver", DEFAULT_DRIVER)))
    except UserInputError as exc:
        raise CampaignError(str(exc)) from None
    driver = given.driver or stored_driver
    port = given.port or config.get("port")
    host = given.host or config.get("host")
    check_connection(driver, port=port, host=host)
    baud = stored_baud if given.baud is None else _check_baud(given.baud, where="--baud")
    camera = stored_camera if given.camera is None else parse_camera(given.camera)
    return EffectiveRig(
        driver=driver, port=port, host=host, baud=baud, camera=camera, driver_given=given.driver is not None
    )


def check_campaign_rig(campaign, rig: EffectiveRig, *, what: str) -> None:
    """Refuse to record ``what`` made on ``rig`` into a campaign of another rig (UserInputError, exit 2).

    Rule: a campaign is one rig (its ``[rig] driver``); its hand-eye, intrinsics,
    references and visits all come from it. ``--driver`` may name another
    driver only for commands that record nothing into a campaign.
    """
    if campaign is None:
        return
    stored = str(campaign.rig_config.get("driver", DEFAULT_DRIVER))
    if rig.driver != stored:
        raise UserInputError(
            f'campaign {campaign.path} is a {stored} rig (campaign.toml [rig] driver = "{stored}"): {what} made '
            f"with --driver {rig.driver} cannot be stored in it; drop --driver, or use a campaign of a "
            f"{rig.driver} rig (`fgcd campaign init DIR --driver {rig.driver}`)"
        )


def check_record_rig(record: dict | None, rig: EffectiveRig, *, name: str, command: str) -> None:
    """Refuse a rig record (``rig/<name>.json``) made on another driver than ``rig``'s (CampaignError, exit 3).

    Records written before they said which rig made them are accepted.
    """
    if not record:
        return
    made = record.get("rig", {}).get("driver") if isinstance(record.get("rig"), dict) else None
    made = made or record.get("driver")
    if made is not None and made != rig.driver:
        raise CampaignError(
            f"rig/{name}.json was made on the {made} rig, and this campaign's rig is {rig.driver}: "
            f"calibrate again on this rig (`{command}`)"
        )


def campaign_rig_section(
    *, driver: str, port: str | None = None, host: str | None = None, baud: int | None = None, camera: str | None = None
) -> dict:
    """The ``[rig]`` section ``fgcd campaign init`` writes, checked (UserInputError, nothing written).

    A hardware rig's values are written out even when defaulted (a GRBL
    stage's baud, the camera), so that campaign.toml says which rig the
    campaign is; the address a driver needs may be given later (``--port``,
    ``--host`` on each command).
    """
    driver = check_driver(driver)
    rig: dict = {"driver": driver}
    rig.update({k: v for k, v in (("port", port), ("host", host)) if v})
    if driver == Driver.GRBL or baud is not None:
        rig["baud"] = DEFAULT_BAUD if baud is None else _check_baud(baud, where="--baud")
    if driver != Driver.SIM or camera is not None:
        rig["camera"] = DEFAULT_CAMERA if camera is None else parse_camera(camera)
    return rig


def calibration_campaign(path: Path | None):
    """The campaign a calibration reads its rig from and stores into (``-c``; None without one; CampaignError)."""
    if path is None:
        return None
    from fgcd_cli.campaign.store import open_campaign

    return open_campaign(path)
