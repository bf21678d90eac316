"""Fitting the network: the training options (``config``), losses (``losses``), distillation targets from a teacher
(``distill``), the training loop (``trainer``), the checkpoint format (``checkpoint``) and the turn classifier
stored in a shipped file (``turn_classifier``)."""
