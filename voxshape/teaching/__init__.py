"""What every teacher's program shares (the terminal client, the web gateway, the simulated
person): what a teacher sees (board), joining a session (session), what it says (sources)."""
