"""sim_bench package."""
