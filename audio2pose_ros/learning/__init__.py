"""Learning: training, evaluation, metrics, distillation and the default model build."""
