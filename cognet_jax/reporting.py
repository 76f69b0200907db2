"""Figures of a finished run (placeholder until the plots module lands)."""


def write_plots(config, algorithm, policy, results, out_dir):
    return []
