"""Shared fixtures: the paper's numbers as independent truth; the bus servos' SDKs given a reply
window a loaded test host can meet (:func:`_sdk_reply_window`)."""

import os

import dynamixel_sdk
import matplotlib
import pytest
import scservo_sdk

matplotlib.use("Agg")
os.environ.setdefault("MPLBACKEND", "Agg")

from gripper_env.paper import PLANTS as PAPER_PLANTS


@pytest.fixture(params=sorted(PAPER_PLANTS))
def paper_plant_name(request):
    return request.param


#: The bus SDKs' latency timer in the tests (ms): a 502 ms reply window (see _sdk_reply_window).
_TEST_LATENCY_TIMER_MS = 250


@pytest.fixture(autouse=True)
def _sdk_reply_window(monkeypatch):
    """The vendors' SDKs as the tests drive them, their reply window widened for a busy host.

    Both SDKs wait ``2 x LATENCY_TIMER + 2`` ms for a status packet (34 ms: ``LATENCY_TIMER`` is
    a USB adapter's 16 ms latency timer), then report no reply. A real servo answers from its own
    microcontroller. A virtual one answers from a thread of the test's process, which shares the
    CPU with the SDK's polling loop. On a 2-core machine at load 15 (test runs side by side),
    threads went unscheduled for 30 to 500 ms, with the request or the reply sitting unread.
    Reads of a virtual STS3215 that timed out: about 1 in 800 with the 34 ms window; at a busier
    time 14 in 1500 with 102 ms, none in 1500 with 502 ms (``LATENCY_TIMER`` 250, used here).
    The tests check what the servo answers, not how soon; a missing servo still times out, only
    later. Sending again after a lost reply is the link's job (issue 33, item 3), not this
    fixture's.
    """
    for sdk in (dynamixel_sdk, scservo_sdk):
        monkeypatch.setattr(sdk.port_handler, "LATENCY_TIMER", _TEST_LATENCY_TIMER_MS)
