"""pfdoa benchmarks (``make bench``): estimator step time, gateway throughput and latency,
gateway memory, firmware size and instruction counts. See docs/benchmarks.md."""
