"""Training: datasets, Joint2Coarse, the neural renderer, losses, metrics, fine-tuning.

Subpackages import torch; ``import training`` alone does not.
"""
