"""PKM graph orchestration, MCAP recording, replay and run reports."""
