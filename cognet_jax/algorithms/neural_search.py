"""What both COGNet-DICE searches (``cognet_weights``, ``cognet_thesis``) report of a run of
their neural policies: its figures and the encoder its observations go through."""

from __future__ import annotations

from cognet_jax.algorithms.engine import Search
from cognet_jax.controllers.figures import neural_plots
from cognet_jax.observations import pipeline_run_files


class NeuralSearch(Search):
    """A search over neural controllers whose observations go through ``self.pipeline``
    (``observations.ObservationPipeline``)."""

    def write_plots(self, config, policy, record: dict, out_dir) -> list:
        """The neural policy's figures (``controllers.figures.neural_plots``)."""
        return neural_plots(self, policy, record, out_dir)

    def run_files(self) -> dict:
        """The pipeline's VAE, if any (``observations.pipeline_run_files``)."""
        return pipeline_run_files(self.pipeline)
