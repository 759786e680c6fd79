"""DLPC350 codec and driver: byte-exact encoders (hand-written from the TI command tables in
the DLPC350 programmer's guide DLPU010), reply/NACK/multi-report decoding, LUT packing,
show_sequence on the fake."""

import time
import warnings

import numpy as np
import pytest

from torchtof.experiment import ExperimentConfig
from torchtof.hardware import dlpc350 as dlp
from torchtof.hardware.errors import FrameTimeoutError, NackError, ProtocolError
from torchtof.hardware.simulated import Faults, SimulatedBench


def hexs(b: bytes, n: int | None = None) -> str:
    return bytes(b[:n] if n else b).hex(" ")


# (command, payload, read, expected bytes with SS = 0x2a), written from the command table
GOLDEN = [
    ("PAT_START_STOP", dlp.payload_start_stop("start"), False, "40 2a 03 00 24 1a 02"),
    ("PAT_START_STOP", dlp.payload_start_stop("pause"), False, "40 2a 03 00 24 1a 01"),
    ("PAT_START_STOP", dlp.payload_start_stop("stop"), False, "40 2a 03 00 24 1a 00"),
    ("POWER_CONTROL", dlp.payload_power(True), False, "40 2a 03 00 00 02 01"),
    ("POWER_CONTROL", dlp.payload_power(False), False, "40 2a 03 00 00 02 00"),
    ("DISP_MODE", dlp.payload_display_mode(True), False, "40 2a 03 00 1b 1a 01"),
    ("DISP_MODE", dlp.payload_display_mode(False), False, "40 2a 03 00 1b 1a 00"),
    ("PAT_DISP_MODE", dlp.payload_pattern_source("video"), False, "40 2a 03 00 22 1a 00"),
    ("PAT_DISP_MODE", dlp.payload_pattern_source("flash"), False, "40 2a 03 00 22 1a 03"),
    ("PAT_TRIG_MODE", dlp.payload_trigger_mode("internal"), False, "40 2a 03 00 23 1a 01"),
    ("PAT_TRIG_MODE", dlp.payload_trigger_mode("vsync"), False, "40 2a 03 00 23 1a 00"),
    ("PAT_TRIG_MODE", dlp.payload_trigger_mode("trig_in_pairs"), False, "40 2a 03 00 23 1a 02"),
    ("PAT_EXPO_PRD", dlp.payload_exposure_period(10000, 10000), False,
     "40 2a 0a 00 29 1a 10 27 00 00 10 27 00 00"),
    ("PAT_EXPO_PRD", dlp.payload_exposure_period(8000, 8500), False,
     "40 2a 0a 00 29 1a 40 1f 00 00 34 21 00 00"),
    ("PAT_CONFIG", dlp.payload_pattern_config(24, False, 24, 1), False,
     "40 2a 06 00 31 1a 17 00 17 00"),
    ("PAT_CONFIG", dlp.payload_pattern_config(2, True, 2, 3), False,
     "40 2a 06 00 31 1a 01 01 01 02"),
    ("MBOX_CONTROL", dlp.payload_mailbox_control("pattern"), False, "40 2a 03 00 33 1a 02"),
    ("MBOX_CONTROL", dlp.payload_mailbox_control("image"), False, "40 2a 03 00 33 1a 01"),
    ("MBOX_CONTROL", dlp.payload_mailbox_control("close"), False, "40 2a 03 00 33 1a 00"),
    ("MBOX_ADDRESS", b"\x00", False, "40 2a 03 00 32 1a 00"),
    ("MBOX_DATA", bytes([0x14, 0x71, 0x00]), False, "40 2a 05 00 34 1a 14 71 00"),
    ("LUT_VALID", b"\x00", False, "40 2a 03 00 1a 1a 00"),
    ("LUT_VALID", b"", True, "c0 2a 02 00 1a 1a"),
    ("STATUS_HW", b"", True, "c0 2a 02 00 0a 1a"),
    ("STATUS_SYS", b"", True, "c0 2a 02 00 0b 1a"),
    ("STATUS_MAIN", b"", True, "c0 2a 02 00 0c 1a"),
    ("GET_VERSION", b"", True, "c0 2a 02 00 05 02"),
    # TI's dlpc350_api.cpp: TRIG_OUT1_CTL 0x1A1D, 3 bytes [invert, rising, falling]
    # (DLPC350_SetTrigOutConfig; 0xBB = 0 us); SOURCE_SEL 0x1A00; VID_SIG_STAT 0x071C
    ("TRIG_OUT1_CTL", dlp.payload_trig_out1(), False, "40 2a 05 00 1d 1a 00 bb bb"),
    ("TRIG_OUT1_CTL", dlp.payload_trig_out1(True, 0xBC, 0xD5), False,
     "40 2a 05 00 1d 1a 01 bc d5"),
    ("SOURCE_SEL", b"", True, "c0 2a 02 00 00 1a"),
    ("SOURCE_SEL", b"\x08", False, "40 2a 03 00 00 1a 08"),
    ("VID_SIG_STAT", b"", True, "c0 2a 02 00 1c 07"),
]


@pytest.mark.parametrize("name,payload,read,expected", GOLDEN,
                         ids=[f"{g[0]}-{i}" for i, g in enumerate(GOLDEN)])
def test_encoder_golden_bytes(name, payload, read, expected):
    reports = dlp.encode(name, payload, seq=0x2A, read=read)
    assert len(reports) == 1 and len(reports[0]) == 64
    n = len(expected.split())
    assert hexs(reports[0], n) == expected
    assert reports[0][n:] == bytes(64 - n)  # zero padded


def test_every_command_has_a_golden_test():
    assert {g[0] for g in GOLDEN} == set(dlp.COMMANDS)


def test_lut_entries_golden():
    assert dlp.lut_entry(5, 1, "RGB", "internal") == 0x007114
    assert dlp.lut_entry(5, 1, "RGB", "external+") == 0x007115
    assert dlp.lut_entry(0, 1, "G", "internal", buffer_swap=True) == 0x042100
    assert dlp.lut_entry(23, 1, "B", "none", invert=True) == 0x01415F
    assert dlp.pack_pattern_lut([0x007114, 0x042100]).hex(" ") == "14 71 00 00 21 04"
    assert dlp.unpack_lut_entry(0x01415F) == {
        "trig": 3, "pattern": 23, "bit_depth": 1, "leds": 4, "invert": True,
        "insert_black": False, "buffer_swap": False, "trig_out_prev": False}


def test_image_lut_two_entries_swapped():
    assert dlp.pack_image_lut([3, 7]).hex(" ") == "07 03"
    assert dlp.pack_image_lut([3, 7, 9]).hex(" ") == "03 07 09"


def test_multi_report_split_and_reassembly():
    payload = bytes(range(72))  # 24 LUT entries: 6 + 72 = 78 bytes -> 2 reports
    reports = dlp.encode("MBOX_DATA", payload, seq=7)
    assert len(reports) == 2 and all(len(r) == 64 for r in reports)
    assert hexs(reports[0], 6) == "40 07 4a 00 34 1a"  # length 74 = 72 + 2
    assert reports[0][6:] == payload[:58]
    assert reports[1][:14] == payload[58:] and reports[1][14:] == bytes(50)
    msg = dlp.decode(reports)
    assert (msg.command, msg.seq, msg.payload, msg.reply_wanted) == ("MBOX_DATA", 7, payload, True)
    asm = dlp.Assembler()
    assert asm.feed(reports[0]) is None and asm.pending
    assert asm.feed(reports[1]).payload == payload and not asm.pending


def test_decode_incomplete_and_extra_reports():
    reports = dlp.encode("MBOX_DATA", bytes(100), seq=1)
    with pytest.raises(ProtocolError, match="incomplete"):
        dlp.decode(reports[:1])
    with pytest.raises(ProtocolError, match="extra report"):
        dlp.decode(dlp.encode("LUT_VALID", b"\x00") + dlp.encode("LUT_VALID", b"\x00"))
    with pytest.raises(ProtocolError, match="64-byte report"):
        dlp.Assembler().feed(b"\x40\x01\x03\x00")


def test_decode_reply_ack_read_and_nack():
    req = dlp.decode(dlp.encode("LUT_VALID", b"", seq=9, read=True))
    reply = dlp.encode_reply(req, b"\x81")
    assert hexs(reply, 5) == "c0 09 01 00 81"
    assert dlp.decode_reply(reply, "LUT_VALID", seq=9).payload == b"\x81"
    ack = dlp.encode_reply(dlp.decode(dlp.encode("DISP_MODE", b"\x01", seq=3)))
    assert hexs(ack, 4) == "40 03 00 00"
    nack = bytes.fromhex("60 03 00 00").ljust(64, b"\0")  # bit 5 set by the device
    with pytest.raises(NackError, match="DISP_MODE: device answered NACK"):
        dlp.decode_reply(nack, "DISP_MODE", seq=3)
    with pytest.raises(ProtocolError, match="sequence number 3, expected 4"):
        dlp.decode_reply(ack, "DISP_MODE", seq=4)
    with pytest.raises(ProtocolError, match="exceeds"):
        dlp.decode_reply(bytes.fromhex("c0 03 ff 00").ljust(64, b"\0"), "STATUS_HW")


@pytest.mark.parametrize("call,match", [
    (lambda: dlp.encode("NOPE"), "unknown command"),
    (lambda: dlp.encode("PAT_START_STOP", b"\x01\x02"), "1-byte payload"),
    (lambda: dlp.encode("MBOX_DATA", b""), "non-empty"),
    (lambda: dlp.encode("DISP_MODE", b"\x01", seq=256), "seq"),
    (lambda: dlp.encode("STATUS_HW", b"\x01", read=True), "no payload"),
    (lambda: dlp.payload_exposure_period(8000, 8100), "period_us - 230"),
    (lambda: dlp.payload_exposure_period(0, 100), "exposure_us"),
    (lambda: dlp.payload_start_stop("go"), "action"),
    (lambda: dlp.payload_pattern_source("hdmi"), "source"),
    (lambda: dlp.payload_pattern_config(0, False, 1, 1), "n_lut - 1"),
    (lambda: dlp.lut_entry(26), "pattern"),
    (lambda: dlp.lut_entry(1, leds="X"), "leds"),
    (lambda: dlp.pack_pattern_lut([]), "1 to 128"),
    (lambda: dlp.pack_bitplanes(np.zeros((25, 2, 2))), "K<=24"),
    (lambda: dlp.pack_bitplanes(np.full((1, 2, 2), 2)), "binary"),
])
def test_bad_inputs(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_bitplanes_round_trip_and_order():
    rng = np.random.default_rng(0)
    pats = rng.integers(0, 2, size=(24, 5, 6)).astype(np.uint8)
    frame = dlp.pack_bitplanes(pats)
    assert frame.shape == (5, 6, 3) and frame.dtype == np.uint8
    for k in range(24):
        np.testing.assert_array_equal(dlp.unpack_bitplane(frame, k), pats[k])
    one = dlp.pack_bitplanes(np.ones((9, 1, 1)))  # planes 0-7 = G, plane 8 = R bit 0
    assert one[0, 0].tolist() == [1, 255, 0]


def test_lut_valid_error_bits():
    assert dlp.lut_valid_errors(0x80) == []
    assert dlp.lut_valid_errors(0x13) == ["exposure or period out of range",
                                          "pattern numbers out of range",
                                          "period - exposure < 230 us (warning)"]
    assert dlp.LUT_FATAL_BITS == 0b11  # TI: bits 2-4 are warnings


def _bench(**faults):
    return SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,), multipath_strength=0.0,
                                           stray_e=0.0), faults=Faults(**faults))


def test_show_sequence_canonical_order_and_state():
    bench = _bench()
    lcr = bench.lightcrafter()
    pats = np.random.default_rng(1).integers(0, 2, size=(6, 8, 8)).astype(np.uint8)
    lcr.show_sequence(pats, exposure_us=5000)
    log = bench.lightcrafter_usb.log
    names = [m.command for m in log]
    assert names == ["PAT_START_STOP", "DISP_MODE", "DISP_MODE", "DISP_MODE", "PAT_DISP_MODE",
                     "PAT_CONFIG", "PAT_TRIG_MODE", "PAT_EXPO_PRD", "TRIG_OUT1_CTL",
                     "MBOX_CONTROL", "MBOX_ADDRESS", "MBOX_DATA", "MBOX_CONTROL", "LUT_VALID",
                     "LUT_VALID", "LUT_VALID", "PAT_START_STOP"]
    # display mode read back, switched, read back again until it took effect
    assert [m.read for m in log[1:4]] == [True, False, True]
    # TRIG_OUT1 active high, rising and falling delay 0xBB = 0 us (DLPC350_SetTrigOutConfig),
    # written with the sequence stopped and before the validation, as TI's API asks
    assert not log[8].read and log[8].payload == bytes([0x00, 0xBB, 0xBB])
    # the validation is polled: the fake reads busy (bit 7) once
    assert [m.read for m in log[13:16]] == [False, True, True]
    fake = bench.lightcrafter_usb
    assert fake.state["config"] == (5, 0, 5, 0) and fake.state["exposure_us"] == 5000
    entries = [dlp.unpack_lut_entry(e) for e in fake.pattern_lut]
    assert [e["pattern"] for e in entries] == list(range(6))
    # VSYNC trigger: floor(16667 / 5000) = 3 patterns per video frame, the first of each
    # waits for the VSYNC (type 1), the others continue (type 3)
    assert fake.state["trigger"] == 0 and [e["trig"] for e in entries] == [1, 3, 3, 1, 3, 3]
    # the DMD showed exactly the patterns, in order
    np.testing.assert_array_equal(np.stack(fake.shown), pats)
    lcr.show_sequence(pats, exposure_us=5000)  # already in pattern mode: no second switch
    assert [m.command for m in log[17:20]] == ["PAT_START_STOP", "DISP_MODE", "PAT_DISP_MODE"]
    assert log[18].read
    assert fake.state["trig_out1"] == (0x00, 0xBB, 0xBB)


def test_display_mode_switch_is_waited_for():
    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,)), realtime=True,
                           mode_latency_s=0.05)
    lcr = bench.lightcrafter()
    t0 = time.monotonic()
    lcr.set_display_mode(True, poll_s=0.005)
    assert time.monotonic() - t0 >= 0.05 and lcr.display_mode() == "pattern"
    reads = [m for m in bench.lightcrafter_usb.log if m.command == "DISP_MODE" and m.read]
    assert len(reads) >= 3  # before, at least once while switching, and the final one


def test_vsync_sequence_must_fit_the_video_frame():
    lcr = _bench().lightcrafter()
    pats = np.zeros((2, 8, 8), dtype=np.uint8)
    with pytest.raises(ValueError, match="does not fit one 16667 us video frame"):
        lcr.show_sequence(pats, exposure_us=20_000)
    bench = SimulatedBench(ExperimentConfig(n=8, roi_px=8, srs=(0.25,)), video_hz=40.0)
    bench.lightcrafter().show_sequence(pats, exposure_us=20_000, video_hz=40.0)  # 25 ms: fits


def test_status_version_and_commands():
    lcr = _bench().lightcrafter()
    assert lcr.status() == {"hw": 1, "sys": 1, "main": 1}
    assert lcr.version()["app"] == 0x03000000
    lcr.standby(True)
    lcr.standby(False)
    assert not lcr.dev.state["standby"]


def test_validation_error_is_decoded():
    bench = _bench()
    lcr = bench.lightcrafter()
    lcr.write("DISP_MODE", b"\x01")
    lcr.write("PAT_DISP_MODE", b"\x00")
    lcr.write("PAT_CONFIG", dlp.payload_pattern_config(2, False, 2, 1))  # 2 entries announced
    lcr.write("PAT_EXPO_PRD", dlp.payload_exposure_period(1000, 1000))
    lcr.load_pattern_lut([dlp.lut_entry(0)])  # ... but only 1 sent, and no video frame
    with pytest.raises(ProtocolError, match="LUT_VALID: .*pattern numbers out of range"):
        lcr.validate()
    with pytest.raises(NackError, match="PAT_START_STOP"):  # start refused: not validated
        lcr.start()


@pytest.mark.parametrize("status", [0x04, 0x08, 0x10])
def test_validation_warnings_are_warnings(status, monkeypatch):
    """TI's DLPC350_StartPatLutValidate documents bits 2-4 as warnings: the sequence stays."""
    bench = _bench()
    lcr = bench.lightcrafter()
    monkeypatch.setattr(bench.lightcrafter_usb, "_validate", lambda: status)
    with pytest.warns(RuntimeWarning, match=r"LUT_VALID status 0x[01][048].*\(warning\)"):
        lcr.validate()
    with pytest.warns(RuntimeWarning, match="warning"):  # the whole load: the sequence runs
        lcr.show_sequence(np.ones((2, 8, 8), dtype=np.uint8), exposure_us=1000)
    assert len(bench.lightcrafter_usb.shown) == 2  # started and shown


def test_an_error_bit_beside_a_warning_bit_rejects_and_names_both(monkeypatch):
    """Status 0x05: bit 0 (TI: an error) and bit 2 (a warning): rejected, both named; the
    LightCrafter's own rule (bits 0-1 fatal, TI's DLPC350_StartPatLutValidate) refuses the
    start."""
    bench = _bench()
    lcr = bench.lightcrafter()
    monkeypatch.setattr(bench.lightcrafter_usb, "_validate", lambda: 0x05)
    with pytest.raises(ProtocolError, match=r"0x05\): .*;.*\(warning\)"):
        lcr.show_sequence(np.ones((2, 8, 8), dtype=np.uint8), exposure_us=1000)
    assert bench.lightcrafter_usb.shown == [] and not bench.lightcrafter_usb.state["validated"]


def test_nack_and_timeout_name_the_command():
    lcr = _bench(nack={"PAT_EXPO_PRD": {0}},
                 reply_timeout={"DISP_MODE": {0, 1, 2}}).lightcrafter()
    with pytest.raises(ProtocolError, match="DISP_MODE: no reply in time"):
        lcr.write("DISP_MODE", b"\x01")  # sent 3 times (retries=2), never answered
    lcr.write("DISP_MODE", b"\x01")  # the next one is answered
    with pytest.raises(NackError, match="PAT_EXPO_PRD"):
        lcr.write("PAT_EXPO_PRD", dlp.payload_exposure_period(1000, 1000))


def test_late_reply_is_discarded_and_the_command_retried():
    """PAT_CONFIG #0 is answered too late: the host times out and sends it again; the late
    reply (old sequence number) then arrives first and is discarded, not taken as the
    reply to the repeat or to the next command."""
    bench = _bench(late_reply={"PAT_CONFIG": {0}}, nack={"PAT_EXPO_PRD": {0}})
    lcr = bench.lightcrafter()
    lcr.write("PAT_CONFIG", dlp.payload_pattern_config(1, False, 1, 1))
    assert bench.lightcrafter_usb.counts["PAT_CONFIG"] == 2 and lcr.stale_replies == 1
    with pytest.raises(NackError, match="PAT_EXPO_PRD"):  # its own reply, not a stale one
        lcr.write("PAT_EXPO_PRD", dlp.payload_exposure_period(1000, 1000))
    # MBOX_DATA is never re-sent (it appends): a missing reply is an error to the caller
    bench = _bench(reply_timeout={"MBOX_DATA": {0}})
    with pytest.raises(ProtocolError, match="MBOX_DATA: no reply"):
        bench.lightcrafter().load_pattern_lut([dlp.lut_entry(0)])
    assert bench.lightcrafter_usb.counts["MBOX_DATA"] == 1


def test_a_device_that_echoes_the_sequence_byte_is_recognised_silently():
    bench = _bench()
    lcr = bench.lightcrafter()
    assert lcr.seq_echo is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lcr.show_sequence(np.ones((2, 8, 8), dtype=np.uint8), exposure_us=1000)
    assert lcr.seq_echo is True and lcr.stale_replies == 0


def test_a_device_without_the_sequence_echo_is_matched_by_order():
    """A reply with sequence byte 0 to the first command (byte 1), with nothing unanswered,
    cannot be a late reply: the driver warns once and matches replies by their order; a
    NACK still reaches the command it answers."""
    bench = _bench(no_seq_echo=True, nack={"PAT_EXPO_PRD": {0}})
    lcr = bench.lightcrafter()
    with pytest.warns(RuntimeWarning, match="does not echo"):
        assert lcr.display_mode() in ("video", "pattern")
    assert lcr.seq_echo is False
    with pytest.raises(NackError, match="PAT_EXPO_PRD"):
        lcr.write("PAT_EXPO_PRD", dlp.payload_exposure_period(1000, 1000))
    runs = []
    for faults in ({"no_seq_echo": True}, {}):  # the same exchange as with the echo
        bench = _bench(**faults)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            bench.lightcrafter().show_sequence(np.ones((2, 8, 8), dtype=np.uint8),
                                               exposure_us=1000)
        fake = bench.lightcrafter_usb
        runs.append(([(m.command, m.payload) for m in fake.log], fake.pattern_lut, fake.state))
    # the same exchange as with the echo, but for the first command, sent once more to confirm
    assert runs[0][0][0] == runs[0][0][1] and runs[0][0][1:] == runs[1][0]
    assert runs[0][1:] == runs[1][1:]


def _zero_reply(data: bytes = b"") -> bytes:
    """A reply with sequence byte 0 (what pyCrafter4500's commands, or a device without the
    echo, leave behind)."""
    return (bytes([dlp.FLAG_REPLY, 0]) + len(data).to_bytes(2, "little") + data).ljust(
        dlp.REPORT_SIZE, b"\x00")


@pytest.mark.parametrize("when", ["first command", "mid-session"])
def test_a_stray_byte_0_reply_does_not_make_an_echoing_device_look_like_one_without(when):
    """A byte-0 reply that arrives after the drain (another program's, or late) while the
    echo is unknown is held, and discarded when the command's own echo follows: no warning,
    and every later command gets its own reply (a NACK the command it answers)."""
    want = _bench().lightcrafter().version()
    bench = _bench(nack={"PAT_EXPO_PRD": {0}})
    fake = bench.lightcrafter_usb
    lcr = bench.lightcrafter()
    if when == "first command":
        fake._late.append(_zero_reply(b"\x55"))  # the drain's read times out before it
    else:
        lcr.read("DISP_MODE")
        lcr.seq_echo = None
        fake._replies.append(_zero_reply(b"\x55"))  # waiting before the next command's reply
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert lcr.display_mode() == "video"  # its own reply, not the stray's 0x55
        assert lcr.seq_echo is True and lcr.stale_replies == 1
        assert lcr.version() == want
        with pytest.raises(NackError, match="PAT_EXPO_PRD"):
            lcr.write("PAT_EXPO_PRD", dlp.payload_exposure_period(1000, 1000))
        lcr.write("PAT_TRIG_MODE", b"\x01")  # answered: not blamed for the NACK above


def test_without_the_echo_the_last_byte_0_reply_is_the_commands():
    """A device without the echo: a stray byte-0 reply after the drain and the command's own
    (also byte 0): the later one is held, and after the confirming resend that one's reply is
    taken; the stray and the first attempt's reply are counted."""
    bench = _bench(no_seq_echo=True)
    fake = bench.lightcrafter_usb
    lcr = bench.lightcrafter()
    fake._late.append(_zero_reply(b"\x55"))
    with pytest.warns(RuntimeWarning, match="does not echo"):
        assert lcr.display_mode() == "video"
    assert lcr.seq_echo is False and lcr.stale_replies == 2
    assert fake.counts["DISP_MODE"] == 2


def test_a_slow_echo_is_not_taken_for_no_echo():
    """An echoing device whose reply to the first command comes after the deadline, with a
    stray byte-0 reply before it: the command is sent again instead of concluding "no echo"
    from the stray; the late echo is discarded and the repeat's own reply taken."""
    bench = _bench(late_reply={"DISP_MODE": {0}})
    fake = bench.lightcrafter_usb
    lcr = bench.lightcrafter()
    lcr._drain()  # the leftovers, as the first command would
    fake._replies.append(_zero_reply(b"\x55"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert lcr.display_mode() == "video"
    assert lcr.seq_echo is True and fake.counts["DISP_MODE"] == 2


def test_a_non_zero_byte_not_ours_proves_the_echo_after_all():
    """Matched by order (no echo learnt), a reply whose byte is non-zero and not this
    command's can only be an echo of an earlier command of ours: the echo is on, the reply
    discarded, and the command's own reply taken."""
    bench = _bench()
    fake = bench.lightcrafter_usb
    lcr = bench.lightcrafter()
    lcr.read("DISP_MODE")
    lcr.seq_echo = False
    fake._replies.append(bytes([dlp.FLAG_REPLY, 7, 1, 0, 0x55]).ljust(dlp.REPORT_SIZE, b"\x00"))
    assert lcr.display_mode() == "video"
    assert lcr.seq_echo is True and lcr.stale_replies == 1


def test_leftover_replies_are_drained_before_the_first_command():
    bench = _bench(no_seq_echo=True)
    fake = bench.lightcrafter_usb
    fake._replies.append(bytes([dlp.FLAG_REPLY, 0, 1, 0, 0x55]).ljust(dlp.REPORT_SIZE, b"\x00"))
    lcr = bench.lightcrafter()
    with pytest.warns(RuntimeWarning, match="does not echo"):
        mode = lcr.display_mode()
    # its own reply, not the leftover 0x55 (counted with the first attempt's confirmed reply)
    assert lcr.stale_replies == 2 and mode == "video"


def test_sequence_bytes_skip_0_when_they_wrap():
    """0 is what a device without the echo answers with: our bytes run 1 … 255, 1, …"""
    lcr = _bench().lightcrafter()
    seqs = [lcr._next_seq() for _ in range(600)]
    assert 0 not in seqs and seqs[:2] == [1, 2] and seqs[254:257] == [255, 1, 2]


def test_without_the_echo_a_late_reply_is_drained_not_misattributed():
    """PAT_CONFIG #0 is answered late by a device without the echo: the late reply is
    drained before the retry, whose byte-0 reply is confirmed by one more attempt; the next
    command (a NACKed PAT_EXPO_PRD) gets its own reply."""
    bench = _bench(no_seq_echo=True, late_reply={"PAT_CONFIG": {0}}, nack={"PAT_EXPO_PRD": {0}})
    lcr = bench.lightcrafter()
    with pytest.warns(RuntimeWarning, match="does not echo"):
        lcr.write("PAT_CONFIG", dlp.payload_pattern_config(1, False, 1, 1))
    assert bench.lightcrafter_usb.counts["PAT_CONFIG"] == 3 and lcr.stale_replies == 2
    with pytest.raises(NackError, match="PAT_EXPO_PRD"):
        lcr.write("PAT_EXPO_PRD", dlp.payload_exposure_period(1000, 1000))


def test_flash_source_uses_image_lut_and_buffer_swaps():
    bench = _bench()
    rng = np.random.default_rng(2)
    a, b = (rng.integers(0, 2, size=(3, 8, 8)).astype(np.uint8) for _ in range(2))
    bench.lightcrafter_usb.flash = {4: dlp.pack_bitplanes(a), 9: dlp.pack_bitplanes(b)}
    lcr = bench.lightcrafter()
    lcr.show_sequence([(4, 0), (4, 2), (9, 1)], exposure_us=2000, source="flash")
    fake = bench.lightcrafter_usb
    assert fake.image_lut == [4, 9]
    assert [dlp.unpack_lut_entry(e)["buffer_swap"] for e in fake.pattern_lut] == [False, False,
                                                                                   True]
    np.testing.assert_array_equal(np.stack(fake.shown), np.stack([a[0], a[2], b[1]]))


def test_video_source_needs_a_video_port():
    bench = _bench()
    lcr = dlp.LightCrafter4500(bench.lightcrafter_usb)
    with pytest.raises(ValueError, match="video port"):
        lcr.show_sequence(np.ones((2, 8, 8)), exposure_us=1000)


def test_external_trigger_waits_for_trig_in():
    bench = _bench()
    cam = bench.camera()
    cam.start()
    lcr = bench.lightcrafter()
    pats = np.stack([np.eye(8, dtype=np.uint8), 1 - np.eye(8, dtype=np.uint8)])
    lcr.show_sequence(pats, exposure_us=1000, trigger="external")
    fake = bench.lightcrafter_usb
    assert [dlp.unpack_lut_entry(e)["trig"] for e in fake.pattern_lut] == [1, 1]
    assert fake.shown == [] and bench.camera_usb.rendered == 0  # nothing until a TRIG_IN edge
    fake.trigger_in(1.0)
    fake.trigger_in(2.0)  # edges one camera frame time apart at least (33 ms at power-up)
    fake.trigger_in(3.0)  # past the end of the sequence: ignored
    np.testing.assert_array_equal(np.stack(fake.shown), pats)
    assert bench.camera_usb.rendered == 2
    # both frames reach the host (the camera's reader thread may already have taken them
    # off the device FIFO), and nothing more
    assert [cam.grab(1.0).frame_id for _ in range(2)] == [0, 1]
    with pytest.raises(FrameTimeoutError):
        cam.grab(0.05)
    cam.stop()
