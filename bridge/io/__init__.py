"""Where frames come from: CAN logs (python-can's readers, chosen by suffix) and live buses."""
