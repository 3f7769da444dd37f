"""Shared by the examples: the demo's server if it runs, else its data directory."""
import argparse

import hvdb


def database(description):
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--server", default="127.0.0.1:7878",
                    help="hvdb-server to use (the demo's, by default)")
    ap.add_argument("--data", default="./data",
                    help="data directory to open instead when no server answers")
    ap.add_argument("--dataset", default="panoptic")
    args = ap.parse_args()
    try:
        db = hvdb.connect(args.server)
    except hvdb.Unavailable:
        db = hvdb.open(args.data)
    return db, args
