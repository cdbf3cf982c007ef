"""The gateway's reassembly under garbage, loss, duplicates and reordering, in virtual time
(tools/gateway_stress.py, a function of the seed): every counter equals what was injected and
memory stays bounded. Here and not in tests/unit: 10^5 frames, half of them under tracemalloc,
take ~15 s of CPU."""

from __future__ import annotations

from tools_support import tool_module


def test_stress_counters_equal_injected_and_memory_bounded():
    """10^5 frames, 10 % garbage bytes, 5 % loss, 1 % duplicates, 1 % swaps (tools/gateway_stress.py
    runs 10^6). Every counter equals what was injected; traced memory after warm-up stays
    under 512 KiB (the bound: 64 open sets, 1024 remembered closed sets, a 65-byte decoder
    buffer; about 0.2 MB measured, generator included)."""
    # Traced from half-way: any state that grew with the input would show as allocations
    # proportional to the 50 000 traced frames (12 500 sets; 0.6 MB even at 50 bytes per set).
    with tool_module("gateway_stress") as stress:
        r = stress.run(100_000, seed=7, warmup_frames=50_000)
        assert stress.check(r) == []
    inj = r["injected"]
    assert 0.09 < inj["garbage_share"] < 0.11
    assert inj["duplicates"] > 500 and inj["swaps"] > 500 and sum(inj["lost"].values()) > 4000
    assert r["gateway"]["errors_total"] > 4000
    assert 0 < r["memory"]["tracemalloc_peak_bytes_after_warmup"] < 512 * 1024
