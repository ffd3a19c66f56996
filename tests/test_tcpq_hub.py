"""The localhost tcpq hub relays LCM messages between clients (127.0.0.1 only, bounded)."""

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
