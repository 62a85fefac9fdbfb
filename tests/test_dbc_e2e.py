"""A foreign DBC with AUTOSAR E2E profile 2 and 5: frames protected with cantools' own functions pass, a
corrupted CRC or a repeated counter is dropped and counted, a gap is counted as lost."""

from __future__ import annotations

import numpy as np
import pytest
from cantools.autosar.end_to_end import apply_profile2_crc, apply_profile5_crc

from edge_monitor.sources.dbc_source import DbcDecoder
from protocol.signal_mapping import MappingError, mapping_from_dict

DBC = """VERSION ""
NS_ :
BS_:
BU_: C M
BO_ 256 Axis0: 8 C
 SG_ Crc : 0|8@1+ (1,0) [0|255] "" M
 SG_ Counter : 8|4@1+ (1,0) [0|15] "" M
 SG_ Speed : 16|16@1- (0.01,0) [-327.68|327.67] "rad/s" M
 SG_ Torque : 32|16@1- (0.0001,0) [-3.2768|3.2767] "" M
BO_ 257 Axis1: 8 C
 SG_ Crc : 0|16@1+ (1,0) [0|65535] "" M
 SG_ Counter : 16|8@1+ (1,0) [0|255] "" M
 SG_ Speed : 24|16@1- (0.01,0) [-327.68|327.67] "rad/s" M
 SG_ Torque : 40|16@1- (0.0001,0) [-3.2768|3.2767] "" M
"""
DATA_IDS = list(range(0x10, 0x20))


def _mapping(tmp_path):
    (tmp_path / "e2e.dbc").write_text(DBC)
    joint = lambda m: {"speed": {"message": m, "signal": "Speed"}, "torque": {"message": m, "signal": "Torque"}}  # noqa: E731
    return mapping_from_dict({
        "kind": "dbc", "dbc": "e2e.dbc", "cycles": {"speeds": [10.0]},
        "joint": {"0": joint("Axis0"), "1": joint("Axis1")},
        "e2e": [{"message": "Axis0", "profile": 2, "data_ids": DATA_IDS},
                {"message": "Axis1", "profile": 5, "data_id": 0x1234}]}, tmp_path / "e2e.toml")


def _frames(counters: list[int]) -> tuple[np.ndarray, np.ndarray]:
    ids, rows = [], []
    for k, c in enumerate(counters):
        p2 = bytearray(8)
        p2[1] = c & 0x0F
        p2[2:4] = int(100 * k).to_bytes(2, "little", signed=True)
        rows.append(bytes(apply_profile2_crc(bytes(p2), DATA_IDS[c & 0x0F])))
        p5 = bytearray(8)
        p5[2] = c & 0xFF
        rows.append(bytes(apply_profile5_crc(bytes(p5), 0x1234)))
        ids += [256, 257]
    return np.array(ids), np.frombuffer(b"".join(rows), dtype=np.uint8).reshape(-1, 8).copy()


def test_profiles_2_and_5_checked_with_cantools(tmp_path):
    decoder = DbcDecoder(_mapping(tmp_path))
    ids, data = _frames([0, 1, 2, 2, 5, 6])         # a repeat, then two lost
    data[2, 3] ^= 0x01                              # profile 2 frame of counter 1: payload corrupted
    out = decoder.decode(ids, data, np.full(ids.size, 8), np.arange(ids.size) * 1e-3)
    c = decoder.c
    assert c.crc_errors == 1
    assert c.repeated == 2                          # counter 2 twice, in both messages
    assert c.counter_lost == 2 + 2 + 1              # 2 → 5 in both; 0 → 2 in profile 2 after the bad frame
    assert out.joints[0].time.size == 4 and out.joints[1].time.size == 5


def test_e2e_mapping_errors(tmp_path):
    with pytest.raises(MappingError, match="profile: 2 or 5"):
        mapping_from_dict({"kind": "dbc", "dbc": "x.dbc", "cycles": {"speeds": [1.0]},
                           "joint": {"0": {"speed": {"message": "a", "signal": "b"},
                                           "torque": {"message": "a", "signal": "c"}}},
                           "e2e": [{"message": "a", "profile": 1}]})
    with pytest.raises(MappingError, match="16 data IDs"):
        mapping_from_dict({"kind": "dbc", "dbc": "x.dbc", "cycles": {"speeds": [1.0]},
                           "joint": {"0": {"speed": {"message": "a", "signal": "b"},
                                           "torque": {"message": "a", "signal": "c"}}},
                           "e2e": [{"message": "a", "profile": 2, "data_ids": [1]}]})
