"""The localhost tcpq hub relays LCM messages between clients (127.0.0.1 only, bounded)."""

import subprocess
import sys
import time

from pydrake.lcm import DrakeLcm

from pcvfe_drake.hardware.tcpq_hub import HubProcess


def test_hub_relays_subscribed_channels_only():
    with HubProcess(port=0) as hub:
        assert hub.url.startswith("tcpq://127.0.0.1:")
        sender, receiver = DrakeLcm(hub.url), DrakeLcm(hub.url)
        got = []
        receiver.Subscribe("PCVFE_TEST", lambda data: got.append(bytes(data)))
        receiver.Subscribe("PCVFE_TEST_EMPTY", lambda data: got.append(b"wrong"))
        time.sleep(0.2)  # the subscription reaches the hub
        for k in range(5):
            sender.Publish("PCVFE_TEST", b"m%d" % k)
            sender.Publish("PCVFE_OTHER", b"not subscribed")
        deadline = time.monotonic() + 5.0
        while len(got) < 5 and time.monotonic() < deadline:
            receiver.HandleSubscriptions(20)
        assert got == [b"m0", b"m1", b"m2", b"m3", b"m4"]


# A client that pumps and publishes on the hub for `seconds`, then prints how many of its own
# messages came back and exits 0. The LCM C library aborts it (SIGABRT) if its hub goes away.
CLIENT = """
import sys, time
from pydrake.lcm import DrakeLcm
lcm, got = DrakeLcm(sys.argv[1]), []
lcm.Subscribe("PCVFE_TEST", lambda data: got.append(1))
end = time.monotonic() + float(sys.argv[2])
while time.monotonic() < end:
    lcm.Publish("PCVFE_TEST", b"x")
    lcm.HandleSubscriptions(10)
print(len(got), flush=True)
"""


def test_a_released_hub_outlives_the_bridge_and_ends_after_its_last_client():
    hub = HubProcess(port=0, idle_exit_s=0.5, detach=True)
    client = subprocess.Popen(
        [sys.executable, "-c", CLIENT, hub.url, "2.0"], stdout=subprocess.PIPE, text=True
    )
    try:
        time.sleep(0.5)  # the client is connected and pumping
        hub.release()  # what `pcvfe vehicle-bridge` does when it ends before the station
        out, _ = client.communicate(timeout=60)
        # Ended by itself, not aborted (-6) by the LCM C library losing its hub.
        assert client.returncode == 0 and int(out) > 0
        assert hub.wait(timeout_s=30) == 0  # the hub ends once its last client left
    finally:
        for proc in (client,):
            if proc.poll() is None:
                proc.kill()
        hub.close()


def test_the_hub_ends_by_itself_when_no_client_comes():
    from pcvfe_drake.hardware.tcpq_hub import LcmTcpqHub, hub_listening

    hub = LcmTcpqHub(port=0).start()
    try:
        assert hub_listening(hub.port)
        assert hub.wait_idle(idle_s=0.05, first_client_s=0.2) == "no client"
    finally:
        hub.close()
    assert not hub_listening(hub.port)
