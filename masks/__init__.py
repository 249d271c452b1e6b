"""2D "anything" masks: generators, bit-packed storage, sampling rules."""
