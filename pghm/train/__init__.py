"""Training: the paper's losses, prior training, two-stage personalisation, evaluation."""
