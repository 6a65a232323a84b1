"""Cable sag through the daemon: the simulator as its own process (`cablebot sim`, the physical
plant with its cables 3 mm steel rope: EA 4.5e5 N and `[sim] cable_mass_kg_per_m`, the reels'
by default, beside `cablebot run` over udp_multicast) and inside the daemon (`[sim] enabled`),
the daemon's reels of the same EA and mass per metre, the paper robot carrying 5 kg. After a
move and settling, the plant's truth (read on `<prefix>/sim/truth` over Zenoh) is within a
millimetre of the target and the published pose within a millimetre of the truth; a pose the
cables cannot hold with their weight is refused."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.daemon_procs import zquery
from tests.service.test_daemon_sim_stretch import SimDaemonRig

STEEL = 0.036


@pytest.mark.timeout(400)
@pytest.mark.parametrize("sim_in_process", [False, True], ids=["cablebot-sim", "in-daemon"])
def test_daemon_with_sag_is_within_a_millimetre(tmp_path: Path, sim_in_process: bool) -> None:
    rig = SimDaemonRig(
        tmp_path,
        4.5e5,
        4.5e5,
        plant_mass_kg_per_m=STEEL,
        model_mass_kg_per_m=STEEL,
        sim_in_process=sim_in_process,
    )
    try:
        rig.arm()
        for target in [(35.0, 20.0, 3.0), (10.0, -5.0, 0.5)]:
            err_target, err_pose = rig.move_and_settle(target)
            assert rig.state() == "HOLDING", rig.log()
            assert err_target < 1e-3, (target, err_target)
            assert err_pose < 1e-3, (target, err_pose)
        reply = zquery(rig.session, f"{rig.prefix}/cmd/move", {"position_m": [0, 0, 6]}, 10.0)
        assert "at the anchor above 495 N" in str(reply.get("error")), reply
        assert rig.state() == "HOLDING"
    finally:
        rig.close()
