"""PKM control laws and the redundant-actuation controller node."""
