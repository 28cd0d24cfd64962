"""The job inbox: the FTP server (aioftp's server side) that nesting software drops programs into."""
