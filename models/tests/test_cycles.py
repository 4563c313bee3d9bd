"""Cycles from a pipeline model (cross/cycles.py) and the book page made from its files."""

import importlib.util
import json
from pathlib import Path

import pytest

from dribble_models import cycles_report

REPOSITORY = Path(__file__).resolve().parents[2]


def cycles_tool():
    spec = importlib.util.spec_from_file_location("cycles", REPOSITORY / "cross" / "cycles.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_blocks_end_at_a_change_of_count_and_at_control_transfers():
    cycles = cycles_tool()
    instructions = {
        0x10: ("mov %eax,%ebx", "f"),
        0x12: ("add $0x1,%eax", "f"),
        0x15: ("jne 0x10", "f"),
        0x17: ("mulps %xmm1,%xmm2", "f"),
        0x1a: ("addps %xmm2,%xmm3", "f"),
        0x1d: ("rep movsb %ds:(%esi),%es:(%edi)", "f"),
        0x1f: ("ret", "f"),
    }
    order = sorted(instructions)
    counts = {0x10: 5, 0x12: 5, 0x15: 5, 0x17: 5, 0x1a: 2, 0x1d: 640, 0x1f: 2}
    blocks = cycles.blocks_of(counts, instructions, order)
    assert [(b["count"], len(b["instructions"]), bool(b.get("string"))) for b in blocks] == [
        (5, 3, False),  # ended by the jump
        (5, 1, False),  # the same count, but after a jump: a new block
        (2, 1, False),  # the count changes
        (640, 1, True),  # a string instruction is costed apart
        (2, 1, False),
    ]


def test_a_string_iteration_costs_by_its_width_and_the_core():
    cycles = cycles_tool()
    assert cycles.string_iteration_cycles("rep movsb %ds:(%rsi),%es:(%rdi)", "sapphirerapids") == 1 / 32
    assert cycles.string_iteration_cycles("rep stos %rax,%es:(%rdi)", "sapphirerapids") == 8 / 32
    assert cycles.string_iteration_cycles("rep movsl %ds:(%esi),%es:(%edi)", "atom") == 1.0


def test_the_page_gives_the_tick_with_the_hosts_band_beside_the_flat_method(tmp_path, monkeypatch):
    monkeypatch.setattr(cycles_report, "PERFORMANCE", tmp_path)
    (tmp_path / "host-check.json").write_text(json.dumps({
        "host_ghz": 4.0, "mcpu": "sapphirerapids", "cases": 1, "median_error": 0.25,
        "error_p10": 0.0, "error_p90": 1.0,
        "rows": [{"policy": "cnn", "isa": "ssse3", "workload": "whole forward", "instructions": 1000,
                  "model_cycles": 500, "measured_cycles": 400, "error": 0.25, "unmodelled_share": 0.0}],
    }))
    (tmp_path / "v5-robot.json").write_text(json.dumps({
        "build": "v5", "isa": "ssse3", "mcpu": "atom", "ghz": 1.6, "policy": "robot", "int8": True,
        "peak_multiply_adds_per_cycle": 2.0,
        "tick": {"instructions": 1_600_000, "cycles": 3_200_000, "instructions_per_cycle": 0.5,
                 "unmodelled_share": 0.0, "hottest_blocks": []},
        "layers": [{"index": 0, "name": "int8 conv 5x5 1->4 +pool", "multiply_adds": 1_600_000,
                    "weight_bytes": 100, "activation_bytes": 1000, "instructions": 800_000,
                    "cycles": 1_600_000, "share_of_peak": 0.5}],
    }))
    page = cycles_report.page()
    # 3.2 M cycles at 1.6 GHz: 2 ms; the host's error from 0 % to +100 %: 1-2 ms; the flat
    # method's 0.7-1.0 a cycle: 1.00-1.43 ms.
    assert "| v5 | robot | 1,600,000 | 0.50 | 2.00 ms | 1.00-2.00 ms | 1.00-1.43 ms | 1.5 ms |" in page
    assert "| 0 | int8 conv 5x5 1->4 +pool | 1,600,000 | 100 | 1,000 | 800,000 | 1,600,000 | 1000.0 | 50% |" in page
    assert "Median error +25%" in page


def test_calls_leave_the_model_and_the_atoms_read_tzcnt_as_bsf():
    cycles = cycles_tool()
    assert cycles.for_the_model("call 0x1234", "atom") is None
    assert cycles.for_the_model("ret", "sapphirerapids") is None
    assert cycles.for_the_model("tzcnt %eax,%ebp", "atom") == "bsf %eax,%ebp"
    assert cycles.for_the_model("tzcnt %eax,%ebp", "sapphirerapids") == "tzcnt %eax,%ebp"
    # AVX and BMI that a host-chosen C library routine brings: not the Atoms' code.
    assert cycles.for_the_model("vmovdqu (%rsi),%ymm1", "silvermont") == ""
    assert cycles.for_the_model("bzhi %edx,%eax,%edx", "atom") == ""
    assert cycles.for_the_model("vmovdqu (%rsi),%ymm1", "sapphirerapids") == "vmovdqu (%rsi),%ymm1"


def test_an_amd_host_is_modelled_by_its_zen_generation():
    cycles = cycles_tool()
    assert cycles.amd_mcpu(0x17, 0x01) == "znver1"
    assert cycles.amd_mcpu(0x17, 0x31) == "znver2"
    assert cycles.amd_mcpu(0x19, 0x01) == "znver3"
    assert cycles.amd_mcpu(0x19, 0x11) == "znver4"  # Genoa
    assert cycles.amd_mcpu(0x19, 0x21) == "znver3"  # Vermeer
    assert cycles.amd_mcpu(0x19, 0x61) == "znver4"  # Raphael
    assert cycles.amd_mcpu(0x1A, 0x02) == "znver5"


def test_a_profile_by_another_llvm_than_the_host_checks_is_refused(tmp_path, monkeypatch):
    cycles = cycles_tool()
    (tmp_path / "models" / "performance").mkdir(parents=True)
    (tmp_path / "models" / "performance" / "host-check.json").write_text(json.dumps({"model": "llvm-mca 22.1.8"}))
    monkeypatch.setattr(cycles, "REPO", tmp_path)
    monkeypatch.setattr(cycles, "llvm_mca", lambda: "llvm-mca-14")
    monkeypatch.setattr(cycles, "llvm_mca_version", lambda: "llvm-mca 14.0.6")
    with pytest.raises(SystemExit, match="apt-get install llvm-22"):
        cycles.require_host_check_model()
    monkeypatch.setattr(cycles, "llvm_mca_version", lambda: "llvm-mca 22.1.8")
    cycles.require_host_check_model()
