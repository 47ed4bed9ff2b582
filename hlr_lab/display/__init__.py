"""What the commands show: the library's results as rich tables, lines and progress displays (as
bluesky's ``LiveTable`` is the library's, not the shell's), so that the command line, the demo and other
programs show the same thing. Each module takes one kind of result; none prints by itself."""
