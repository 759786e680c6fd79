"""Register sequences of the OPT8241 driver written from TI's Voxel SDK (3dtof/voxelsdk) and
the OPT9221 register map (TI3DToF/OPT9221.dml), on a fake USB device that records every
control transfer: the PLL update pulse, the integration duty cycle written again after the
frame's cycle count changes, the ``op_overflow`` flag, and the bulk-read timeout."""

import time
from dataclasses import asdict

import pytest
import torch

from torchtof.experiment import ExperimentConfig
from torchtof.hardware import opt8241 as opt
from torchtof.hardware.errors import FrameError, HardwareError, usb_exceptions
from torchtof.hardware.simulated import Faults, SimulatedBench

# register addresses (OPT9221.dml, bank 0 -> slave 0x58, bank 3 -> slave 0x5C)
MOD_PLL_UPDATE = 0x5802  # bank 0 reg 2 bit 2 (id 7984)
PLL_VALUES = {0x580C, 0x580D, 0x580F}  # mod_m/_frac 1 (reg 12), 2 (reg 13); mod_n/ps (reg 15)
PIX_CNT_MAX = 0x5882  # bank 0 reg 130 bits 0-21
QUAD_CNT_MAX = 0x5883  # bank 0 reg 131 bits 0-3
INTG_DUTY_CYCLE = 0x5C4C  # bank 3 reg 76 bits 0-5; hdr_scale bits 6-8 in the same register
FLAGS = 0x5C63  # bank 3 reg 99: op_overflow bit 20, pix_cnt_max_set_failed 22, intg_… 23
QVGA = {0x5C2F: 240 << 14, 0x5C30: 320 << 14}  # bin_row_count, bin_col_count
INITIALISED = {0x5C2E: 0x72}  # tillum_slv_addr after TintinCDKCamera::_init


class Recorder:
    """A pyusb-like device keeping 24-bit registers and logging every control transfer as
    ``("r" | "w", address, value)``; ``on_write(address, value)`` may change the registers
    after a write (what the chip does in response)."""

    def __init__(self, regs=None, on_write=None):
        self.regs, self.log, self.on_write = dict(regs or {}), [], on_write
        self.read_timeouts: list[int] = []

    def ctrl_transfer(self, rtype, req, wvalue, windex, data, timeout=None):
        address = wvalue << 8 | windex  # the 3-byte OPT9221 slaves: no shift
        if rtype == 0x40:
            value = int.from_bytes(bytes(data), "little")
            self.regs[address] = value
            self.log.append(("w", address, value))
            if self.on_write is not None:
                self.on_write(self, address, value)
            return len(data)
        self.log.append(("r", address, self.regs.get(address, 0)))
        return bytearray(self.regs.get(address, 0).to_bytes(data, "little"))

    def read(self, endpoint, size, timeout=None):
        """No frame ever comes: the read times out (after a short wall wait)."""
        self.read_timeouts.append(timeout)
        time.sleep(0.002)
        raise usb_exceptions()[1]("Operation timed out", errno=110)

    def writes(self, address=None):
        return [(a, v) for k, a, v in self.log if k == "w" and address in (None, a)]


# -- 1. PLL update: OPT9221.dml id 7984 --------------------------------------------------------
@pytest.mark.parametrize("freq,quad_reg", [(30e6, 0x04), (48e6, 0x04), (40e6, 0x06)])
def test_mod_pll_update_is_pulsed_1_then_0_after_the_last_pll_write(freq, quad_reg):
    """DML id 7984: "After updating the PLL registers, set this register to 1 and then back
    to 0 to update the PLL frequency" (ToFTintinCamera::_init ends with that pulse): after
    the last write of a PLL value, mod_pll_update goes 1 and then 0, and ends at 0."""
    dev = Recorder({QUAD_CNT_MAX: quad_reg})
    opt.OPT8241(dev).set_modulation_frequency(freq)
    w = dev.writes()
    last = max(i for i, (a, _) in enumerate(w) if a in PLL_VALUES)
    after = [(v >> 2) & 1 for a, v in w[last + 1:] if a == MOD_PLL_UPDATE]
    assert any(after[i:i + 2] == [1, 0] for i in range(len(after) - 1)), after
    assert after[-1] == 0 and (dev.regs[MOD_PLL_UPDATE] >> 2) & 1 == 0


# -- 2. intg_duty_cycle after pix_cnt_max / quad_cnt_max: ToFCamera::_setFrameRate ------------
def test_set_frame_time_writes_the_duty_cycle_again_as_set_frame_rate_does():
    """ToFCamera::_setFrameRate: set PIX_CNT_MAX, read PIX_CNT_MAX_SET_FAILED, get INTG_TIME
    (reads INTG_DUTY_CYCLE and INTG_DUTY_CYCLE_SET_FAILED) and set it back (writes
    INTG_DUTY_CYCLE, reads INTG_DUTY_CYCLE_SET_FAILED). The value written is the one held
    (duty 9 -> 14 % -> 9), hdr_scale (bits 6-8 of the same register) kept."""
    reg76 = 3 << 6 | 9  # hdr_scale 3, intg_duty_cycle 9
    dev = Recorder({PIX_CNT_MAX: 100000, QUAD_CNT_MAX: 0x44, INTG_DUTY_CYCLE: reg76})
    opt.OPT8241(dev).set_frame_time(9500)
    w = dev.writes()
    assert [a for a, _ in w] == [QUAD_CNT_MAX, PIX_CNT_MAX, INTG_DUTY_CYCLE]
    assert w[-1] == (INTG_DUTY_CYCLE, reg76)
    i_pix = dev.log.index(("w", PIX_CNT_MAX, 114000))
    i_duty = dev.log.index(("w", INTG_DUTY_CYCLE, reg76))
    assert ("r", FLAGS, 0) in dev.log[i_pix:i_duty]  # pix_cnt_max_set_failed read between
    assert ("r", FLAGS, 0) in dev.log[i_duty:]  # intg_duty_cycle_set_failed read back after


def test_a_duty_cycle_refused_after_the_new_frame_time_raises():
    """The chip sets intg_duty_cycle_set_failed when the duty cycle is written again for the
    new frame: checked after that write, as IntegrationTimeParameter::set does."""
    def refuse(dev, address, value):
        if address == INTG_DUTY_CYCLE:
            dev.regs[FLAGS] = dev.regs.get(FLAGS, 0) | 1 << 23

    dev = Recorder({PIX_CNT_MAX: 100000, QUAD_CNT_MAX: 0x44, INTG_DUTY_CYCLE: 9},
                   on_write=refuse)
    with pytest.raises(HardwareError, match="intg_duty_cycle_set_failed"):
        opt.OPT8241(dev).set_frame_time(9500)


def test_a_quad_count_change_keeps_the_frame_rate_as_ti_does():
    """TintinUnambiguousRangeParameter::set (ToFTintinCamera.cpp) reads the frame rate, sets
    QUAD_CNT_MAX and calls _setFrameRate with the old rate: PIX_CNT_MAX = old rate's cycles /
    (new quads · sub-frames), PIX_CNT_MAX_SET_FAILED read, INTG_TIME read and written back.
    Here 6 -> 4 quads at pix 100000, one sub-frame: 100000 · 6 / 4 = 150000 (12.5 ms kept)."""
    dev = Recorder({**QVGA, QUAD_CNT_MAX: 0x16, INTG_DUTY_CYCLE: 9, PIX_CNT_MAX: 100000})
    cam = opt.OPT8241(dev, mode="quad", quads=4)
    cam.configure()
    w = dev.writes()
    i = w.index((QUAD_CNT_MAX, 0x14))
    after = [x for x in w[i + 1:] if x[0] in (PIX_CNT_MAX, INTG_DUTY_CYCLE)]
    assert after[:2] == [(PIX_CNT_MAX, 150000), (INTG_DUTY_CYCLE, 9)]
    assert [v for a, v in w if a == PIX_CNT_MAX] == [150000]  # once: no period given
    i_pix = dev.log.index(("w", PIX_CNT_MAX, 150000))
    i_duty = dev.log.index(("w", INTG_DUTY_CYCLE, 9))
    assert ("r", FLAGS, 0) in dev.log[i_pix:i_duty]  # pix_cnt_max_set_failed read between
    assert cam.frame_time_us == pytest.approx(100000 * 6 / 48)


def test_a_quad_count_change_with_a_period_sets_the_period_s_frame_time_once():
    """With a pattern period the frame time follows the period (less the margin) at the
    quad-count change, in TI's QUAD, PIX, INTG order, and is not written a second time."""
    dev = Recorder({**QVGA, QUAD_CNT_MAX: 0x16, INTG_DUTY_CYCLE: 9, PIX_CNT_MAX: 100000})
    opt.OPT8241(dev, mode="quad", quads=4).configure(period_us=50000, margin_us=500)
    w = dev.writes()
    i = w.index((QUAD_CNT_MAX, 0x14))
    pix = [v for a, v in w if a == PIX_CNT_MAX]
    assert pix == [49500 * 48 // 4]  # 594000
    assert [a for a, _ in w[i + 1:i + 4] if a != QUAD_CNT_MAX] == [PIX_CNT_MAX, INTG_DUTY_CYCLE]


def test_a_frame_time_the_new_quad_count_cannot_hold_raises_before_any_write():
    """4 -> 6 quads at pix 50000 (the board's minimum, TintinCDKCamera::_init) would need
    pix 50000 · 4 / 6 = 33333 < 50000 to keep the frame rate: a ValueError, nothing written."""
    dev = Recorder({**QVGA, QUAD_CNT_MAX: 0x14, INTG_DUTY_CYCLE: 9, PIX_CNT_MAX: 50000})
    with pytest.raises(ValueError, match=r"pix_cnt_max = 33333 < 50000.*give the pattern "
                                         r"period: configure\(period_us=\.\.\.\)"):
        opt.OPT8241(dev, mode="quad", quads=6).configure()
    assert dev.writes() == []


def test_a_period_too_short_for_the_board_raises_before_any_write_quads_unchanged_too():
    """A period whose frame needs pix_cnt_max < 50000 (4 quads, 1 sub-frame: < 4166.7 us) is
    refused before tg_dis is written, whether or not the quad count changes."""
    for quad_reg in (0x14, 0x16):  # 4 quads (unchanged), 6 quads (changed to 4)
        dev = Recorder({**QVGA, QUAD_CNT_MAX: quad_reg, INTG_DUTY_CYCLE: 9, PIX_CNT_MAX: 100000})
        with pytest.raises(ValueError, match="OPT8241.configure: a frame of at most 3500 us "
                                             "needs pix_cnt_max = 42000 < 50000"):
            opt.OPT8241(dev, mode="depth", quads=4).configure(period_us=4000, margin_us=500,
                                                                 spacing_us=20000)
        assert dev.writes() == []


# -- 3. bulk-read timeout -----------------------------------------------------------------------
def _reads(slave):
    dev = Recorder()
    cam = opt.OPT8241(dev, slave=slave)
    cam._start_reader()
    t0 = time.monotonic()
    while not dev.read_timeouts and time.monotonic() - t0 < 5:
        time.sleep(0.001)
    t0 = time.monotonic()
    cam._stop_reader()
    return dev.read_timeouts, time.monotonic() - t0


def test_slave_mode_reads_wait_at_least_a_second_master_mode_keeps_ti_s_200_ms():
    """Master mode: TI's USBBulkStreamer reads with a 200 ms timeout (Voxel/USBBulkStreamer.cpp).
    Slave mode: the camera idles between sequences, so a short timeout often cuts a frame's
    transfer (pyusb drops what it had read): the reads wait >= 1 s; the reader still stops
    on the halt event (the fake's reads return at once)."""
    slave, stop_s = _reads(True)
    assert slave and min(slave) >= 1000 and stop_s < 1.0
    master, _ = _reads(False)
    assert master and set(master) == {200}


# -- 6. op_overflow: OPT9221.dml id 6378, bank 3 reg 99 bit 20 ----------------------------------
def test_check_output_overflow_raises_clears_and_counts_only_when_set():
    dev = Recorder({FLAGS: 1 << 20})
    cam = opt.OPT8241(dev)
    with pytest.raises(FrameError, match="op_overflow"):
        cam.check_output_overflow()
    assert dev.writes(FLAGS) == [(FLAGS, 0)]  # "Write a '0' to reset the state"
    assert cam.stats["op_overflow"] == 1
    dev.log.clear()
    cam.check_output_overflow()  # clear: a read, nothing written, nothing raised
    assert dev.writes() == [] and ("r", FLAGS, 0) in dev.log


def test_check_overflow_false_reads_nothing_and_raises_nothing():
    """Whether op_overflow fires only on an overrun is device-only: the check can be off."""
    dev = Recorder({FLAGS: 1 << 20})
    cam = opt.OPT8241(dev, check_overflow=False)
    cam.check_output_overflow()
    assert dev.log == [] and cam.stats["op_overflow"] == 0
    with pytest.raises(TypeError, match="check_overflow"):
        opt.OPT8241(dev, check_overflow=1)


TINY = ExperimentConfig(n=8, roi_px=8, srs=(0.125,), shot=None, read_noise_e=0.0)


def _run(path, **faults):
    from torchtof.hardware import acquire

    bench = SimulatedBench(TINY, faults=Faults(**faults))
    cam = bench.camera()
    res = acquire(path, bench.lightcrafter(timeout_ms=100), cam, n=8, sr=0.125, block=8,
                  progress=False, retries=2, frame_timeout_s=0.15,
                  metadata={"simulation": {"config": asdict(TINY), "seed": 0}})
    return res, bench, cam


def test_start_clears_op_overflow_before_streaming():
    bench = SimulatedBench(TINY)
    fake = bench.camera_usb
    fake._set("op_overflow", 1)  # left by an earlier run
    cam = bench.camera()
    cam.start()
    try:
        assert fake.field("op_overflow") == 0
        tg_dis, flags = opt.REGISTERS["tg_dis"], opt.REGISTERS["op_overflow"]
        clear = [i for i, (a, v) in enumerate(fake.writes)
                 if a == flags.address and not flags.get(v)]
        run = [i for i, (a, v) in enumerate(fake.writes)
               if a == tg_dis.address and not tg_dis.get(v)]
        assert clear and run and clear[0] < run[-1]  # cleared before tg_dis = 0
    finally:
        cam.stop()


def test_an_output_overflow_discards_and_repeats_the_sequence(tmp_path):
    """op_overflow set while frame 5 is sent (the frame itself arrives whole): the sequence is
    shown again and the buckets equal a clean run's; without it nothing is retried."""
    from torchtof.hardware import load_buckets

    res, _, cam = _run(tmp_path / "o.zarr", op_overflow={5})
    assert res.retries == 1 and cam.stats["op_overflow"] == 1
    ref, _, ref_cam = _run(tmp_path / "c.zarr")
    assert ref.retries == 0 and ref_cam.stats["op_overflow"] == 0
    a, b = load_buckets(tmp_path / "o.zarr")[0], load_buckets(tmp_path / "c.zarr")[0]
    for k in a:
        assert torch.equal(a[k], b[k]), k


def test_an_overflow_of_a_failed_attempt_does_not_fail_the_next(tmp_path):
    """Frame 3 is both short and overflowed: the short frame fails the attempt, the retry
    clears op_overflow, and the repeated sequence passes (one retry, not two)."""
    res, _, cam = _run(tmp_path / "o.zarr", op_overflow={3}, corrupt={3})
    assert res.retries == 1 and cam.stats["op_overflow"] == 0


def test_a_persistent_overflow_stops_the_run_naming_the_flag(tmp_path):
    with pytest.raises(FrameError, match="op_overflow"):
        _run(tmp_path / "o.zarr", op_overflow=set(range(0, 200)))


def test_the_simulated_flag_is_reset_only_by_a_written_0():
    bench = SimulatedBench(TINY)
    cam = bench.camera()
    bench.camera_usb._set("op_overflow", 1)
    cam.write_field("op_overflow", 1)  # a 1 does not set or reset it (simulator choice)
    assert bench.camera_usb.field("op_overflow") == 1
    cam.write_field("op_overflow", 0)
    assert bench.camera_usb.field("op_overflow") == 0
    cam.write_field("op_overflow", 1)
    assert bench.camera_usb.field("op_overflow") == 0


def test_the_fault_plan_accepts_op_overflow():
    assert Faults.from_dict({"op_overflow": [1, 2]}).op_overflow == {1, 2}
    with pytest.raises(ValueError, match="op_overflow"):
        Faults.from_dict({"op_overflow": [-1]})



def test_acquire_no_overflow_check_records_what_the_flag_would_stop(tmp_path, capsys):
    """An op_overflow set on every frame stops the run; with --no-overflow-check the same run
    completes (the frames themselves are whole)."""
    pytest.importorskip("zarr", minversion="3")
    import json

    from torchtof.cli import main

    args = ["acquire", "--simulated", "--scene", "sky", "--sr", "0.25", "--n", "8",
            "--roi-px", "16", "--noise-free", "--no-progress",
            "--sim-faults", json.dumps({"op_overflow": list(range(400))})]
    assert main([*args, "-o", str(tmp_path / "a.zarr")]) != 0
    assert "op_overflow" in capsys.readouterr().err
    assert main([*args, "--no-overflow-check", "-o", str(tmp_path / "b.zarr")]) == 0
