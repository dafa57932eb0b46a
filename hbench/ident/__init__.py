"""Identification: the method interface, the automatic structure selection, and the paper's
polyphase numerics every method shares."""
