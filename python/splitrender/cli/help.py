"""The help texts of the ``splitrender`` subcommands, in one place to read and proofread:
``HELP[name]`` is a subcommand's line in its parent's list, ``DESCRIPTION[name]`` its ``--help``
text (argparse re-wraps it). :func:`splitrender.cli.args.command` looks both up by name."""

from __future__ import annotations

HELP: dict[str, str] = {
    "example": "reproject a synthetic dynamic scene with every method and write PNGs",
    "render": "render a recording of a built-in scene or a scene description (server buffers "
              "+ ground truth)",
    "encode": "encode a recording into a stream file (HEVC + zstd, versioned packets)",
    "dataset": "export a recording to, or import one from, the authors' dataset layout",
    "dataset export": "write a recording in the authors' dataset layout",
    "dataset import": "read a dataset in the authors' layout into a recording",
    "demo": "render, encode, stream and reproject a built-in dynamic scene; video + metrics",
    "play": "play a recording or stream file through the network model and the client",
    "eval": (
        "the paper's experiments (Tables 1-3, Fig. 6) on the built-in scenes: JSON, "
        "Markdown, plots"
    ),
    "bench": "time client decoding and reprojection per method on a built-in recording",
    "serve": "serve live split rendering over QUIC: render at the predicted pose, stream",
    "connect": "connect to `splitrender serve`: display at f_c, send poses, write a report",
    "relay": "a seeded UDP relay on 127.0.0.1 with delay, jitter, loss and a bandwidth cap",
}

DESCRIPTION: dict[str, str] = {
    "example": (
        "Render server frames 0 and 1 (10 FPS) of the synthetic dynamic scene (main camera "
        "plus two auxiliary cameras), reproject client frame 7 at 120 FPS (between them) at "
        "the client's own pose with every method, write <method>.png, ground_truth.png and "
        "montage.png to --out, and print each method's mean absolute error (MAE, 0-255) "
        "against the ground truth. Pixels a method leaves unmatched stay black."
    ),
    "render": (
        "Render SCENE with the reference renderer into a recording (docs/recording-format.md): "
        "every buffer of the main and both auxiliary cameras for every server frame (10 FPS, "
        "4 shadow subframes), the ground-truth client frames (120 FPS) and the client poses. "
        "Client motion: the scene's head-box path with its deterministic deviation, the server "
        "predicting with a 100 ms delay; or a recorded head trace (--trace), re-anchored at "
        "the path's start. The recording is written to DIR.partial-<pid> and renamed to DIR "
        "when complete. Rendering the same arguments twice gives identical bytes. Time: on 2 "
        "CPU cores about 0.8 s per server frame and 0.23 s per client frame at scale 0.125 "
        "(320x180, 3x3 colour samples), about 4x that at 0.25 (640x360); the defaults take "
        "about 70 s."
    ),
    "encode": (
        "Encode every server frame of the recording REC (from `splitrender render`) into a "
        "stream file (docs/stream-format.md): colour and shadow colours in 8-bit HEVC, depth "
        "and motion in 12-bit HEVC, shadow bitfields losslessly with zstd, split over the "
        "cameras (main 60 %, auxiliary 20 % each) and buffers (colour 50 %, depth 20 %, "
        "motion 20 %, shadow colours 10 %). Prints the achieved Mb/s per buffer, per camera "
        "and in total. The file is written under a temporary name and renamed when complete."
    ),
    "dataset": (
        "Convert between recordings (`splitrender render`, docs/recording-format.md) and "
        "the dataset layout of the paper's reference implementation (docs/dataset-format.md: "
        "per camera a directory with cam.json, color/NNNN.png, depth/NNNN.exr, "
        "forward/backwardFlowField/NNNN.exr and the forward/backward shadow PNGs; the client "
        "cameras and ground truth in a client directory). See `splitrender dataset export "
        "--help` and `splitrender dataset import --help`."
    ),
    "dataset export": (
        "Write the recording REC in the authors' dataset layout under DIR (created; it must "
        "not exist or be empty), as splitrender.export_dataset does: the main camera in "
        "DIR/main/, our auxiliary cameras in DIR/<--aux-names>/, the client's cameras and "
        "ground truth (the left eye of a stereo recording) in DIR/<--client>/. Depth and "
        "motion are written as half floats (relative error <= 2^-11); colours, shadow bits "
        "and matrices are exact. The rates go to every cam.json (serverFps, shadowFps = "
        "serverFps x subframes, clientFps); the scene name, scale and client motion of the "
        "manifest are not part of the layout."
    ),
    "dataset import": (
        "Read the dataset in the authors' layout under DIR, as splitrender.import_dataset "
        "does (main camera in DIR/main/, the two auxiliary cameras --aux, the client cameras "
        "and ground truth in --client; converted to our conventions, see "
        "docs/dataset-format.md), and write it as the recording REC, which `splitrender "
        "play`, `encode` and the API read like a rendered one. Server frame k is at "
        "k / serverFps, client frame n at n / clientFps; the recording lasts N / clientFps "
        "s for the first N client frames, those whose times lie at or before the last server "
        "frame's (one at that very time is kept), so that every client frame lies between "
        "two server frames or on the last; the later ones are left out. Its manifest says "
        "scene = the folder's name, variant 'dataset', client_motion {source: 'dataset'}, "
        "samples 1 (unknown) and the scale, near and far derived from the main camera "
        "(width / 2560, its projection). "
        "Buffers the layout has no slot for (frame 0's backward ones) are zero: no motion, "
        "no shadow change. The client directory must have color/ (the ground truth) and "
        "the client cameras the main camera's size. The frames are read and written one at a "
        "time. REC is written as REC.partial-<pid> and renamed when complete (an image "
        "that cannot be read stops the import and leaves REC as it was)."
    ),
    "demo": (
        "The whole pipeline on a built-in dynamic scene: render the server frames (10 FPS, "
        "main + 2 auxiliary cameras, every buffer) and the ground-truth client frames "
        "(120 FPS, at the client's actual pose, which deviates from the server's predicted "
        "one; with --stereo both eyes, IPD 7 cm); encode the server frames at --bitrate and "
        "decode them; play them through the network model (by default the ideal link; see "
        "the network model options) and the client with every method; score each method "
        "against the ground truth (SSIM, FLIP, PSNR, VMAF; first and last 12 client frames "
        "excluded; with --stereo per eye, the rows holding the mean of both eyes and "
        "summary.json each eye's too). Writes to --out: video.mp4 (ground truth "
        "| ours | FLIP error map of ours, side by side, at --video-fps), stills/*.png "
        "(three client frames: ground truth, every method, the FLIP map, the side-by-side; "
        "the left eye with --stereo), "
        "summary.md and summary.json (the network settings; per method: ssim, flip, psnr, "
        "vmaf, mbps, frames, modes), "
        "and prints the table. The defaults (courtyard at 256x144, 1 s) take about 20 seconds "
        "on 2 CPU cores; time grows with scale^2 x seconds."
    ),
    "play": (
        "Play SOURCE through the network model (by default the ideal link; see the network "
        "model options) and the client with --method, and score the client frames against the "
        "ground truth (SSIM, FLIP, PSNR, VMAF; first and last 12 client frames excluded). "
        "SOURCE is a recording directory (`splitrender render`; its server frames are played "
        "uncompressed, or encoded and decoded at --bitrate), a stream file (`splitrender "
        "encode`; --recording gives the recording it was encoded from, for the client poses "
        "and the ground truth), or a built-in scene name (rendered at --scale/--seconds into "
        "OUT/recording first); or, with --dataset DIR instead of SOURCE, a dataset in the "
        "authors' layout (imported into OUT/recording first, as `splitrender dataset import` "
        "does). Writes OUT/frames/NNNN.png per client frame (or OUT/client.mp4 with --video) "
        "and OUT/play.json (the source, the method, the network settings, the mode counts, "
        "the mode of every client frame, every server frame's arrival time in seconds or "
        "null when lost, the metrics); prints the mode counts (interpolate, extrapolate, "
        "hold) and the metrics. A stereo recording plays its left eye, or with --stereo "
        "both eyes (OUT/frames/left/, OUT/frames/right/ or OUT/client_left.mp4, "
        "OUT/client_right.mp4), with the metrics per eye and their mean."
    ),
    "eval": (
        "Table 1: every --methods x --scenes x --variants on uncompressed server frames "
        "(l = 0). Table 2: ours on the dynamic scenes with --delays extra client "
        "frames, compressed at --bitrate, plus ours_extrapolate (l = 0). Table 3 (--stereo): "
        "every method, mono vs stereo, compressed. Figure 6 (--bitrates, on --rd-scenes): "
        "every method at each bitrate plus the references 'video_streaming' (the ground "
        "truth as one 120 FPS HEVC video) and 'timewarp_10fps/_30fps/_60fps' (main colour "
        "and depth rendered at 10/30/60 FPS with 100/33.3/16.7 ms prediction, timewarped); "
        "prints the bitrates at which ours reaches VMAF 60 and 80. 'video_interp' (a "
        "--methods entry, not in Tables 2-3) is FFmpeg's minterpolate of the server colour "
        "video from 10 to 120 FPS. Recordings are rendered once per "
        "(scene, variant) into OUT/recordings/ and reused. Every experiment plays through "
        "the network model given by the network model options (default: the ideal link), "
        "with l = 0 but in Table 2. With --dataset DIR (a dataset in the authors' layout, "
        "imported into OUT/recordings/<DIR's name>-dataset first) instead of the built-in "
        "scenes: Table 1 only, every method on it as the scene <DIR's name> (variant "
        "'dataset'), at its own size, rates and length. Writes OUT/results.json (a list "
        "of rows with the keys scene, variant, method, bitrate_mbps (null: uncompressed), "
        "delay, stereo, ssim, flip, psnr, vmaf, mbps, frames, network (the link's "
        "bandwidth_mbps, latency_ms, jitter_ms, loss, seed, extra_delay_frames; null for "
        "video_interp and video_streaming, which bypass it)), OUT/tables.md and "
        "OUT/delays.png (+ OUT/rate_distortion.png). The defaults take about 3 minutes on 2 "
        "CPU cores (about 1 minute per scene)."
    ),
    "bench": (
        "Render (once; cached in the temporary directory) two server frames of SCENE at "
        "--scale, encode them at the paper's 40 Mb/s scaled by pixel count and time their "
        "decoding (median ms per server frame), then time reproject() between the two "
        "decoded frames per method on --frames client frames (median, after half a second of "
        "untimed frames). "
        "Prints per method: ms per client frame (median, and the slowest), FPS, ns per output "
        "pixel, MB touched and effective GB/s, where bytes touched = the source buffers the "
        "method reads (ours: colour, depth, one motion and one shadow direction of every "
        "camera of both frames) + the output written (W*H*3), intermediates not counted. With "
        "--backend wgpu the pair is uploaded once and each client frame uploads its pose and "
        "downloads the image. "
        "Also per method: the memory-copy floor (a copy of the bytes touched on as many threads "
        "as the methods run on, or on one where that is faster, measured in the same run) and "
        "the frame time's ratio to it, and the share of the machine's CPU time a virtual "
        "machine's host took while the method was timed (steal %, from /proc/stat; n/a where "
        "the platform does not count it): a row timed while the host took part of the cores "
        "is slower for that. Time on 2 cores at the default scale "
        "0.5 (1280x720, the Targets' size): about 30 s the first time (rendering), about 15 s "
        "with the cache. With --realtime: the real-time client loop instead, for --seconds at "
        "wall-clock --fps (default 120 FPS), on --scene's server frames (rendered and encoded "
        "once at the paper's rate scaled by pixel count, cached in the temporary directory; "
        "looped when --seconds is longer than the scene) or on --stream FILE; each server "
        "frame arrives when the server would send it (one server frame ahead) and is decoded "
        "and prepared on a worker thread while the display renders every refresh at the "
        "client's pose. Prints frame-time p50/p95/p99/max, the display threads' CPU time per "
        "frame, deadline misses (count and %, and what made each late: a late start, more "
        "CPU than the median frame of its mode, or threads that waited), dropped refreshes, "
        "modes, "
        "decode and pair-preparation ms per server frame, the newest server frame's age at "
        "display, CPU use, the host's share of the machine's CPU time (steal) and the "
        "garbage collections the display ran between its frames "
        "(Python's collector is kept out of them); --plot FILE also draws them as a PNG (each "
        "display frame's time "
        "from its refresh to done by mode, the misses, the newest server frame's age). "
        "--exclusive: the display waits, off the clock, until the worker "
        "has decoded and prepared each arriving frame, so that the deadlines measure the "
        "display frames alone (what the reprojection costs without decoding beside it). "
        "--worker-priority idle|low|normal: how the worker yields the cores to the display "
        "(default idle: Linux SCHED_IDLE, it runs only on cores the display leaves idle; low: "
        "nice 10). --prepare-threads N: the threads of the worker's pair preparation (default "
        "1; at the worker's priority, so they take the cores the display leaves). "
        "--display-priority realtime|normal: how the display's threads are "
        "scheduled while they show frames (default realtime: Linux SCHED_RR where permitted, so "
        "that no other thread takes their core in the middle of a frame; the report's display "
        "scheduling says what they got)."
    ),
    "serve": (
        "Serve live split rendering sessions over QUIC (docs/protocol.md, docs/live.md), one at "
        "a time. Per session: receive the client's poses (datagrams), predict the head pose at "
        "each server frame's time (--predictor), render every buffer with the reference "
        "renderer at --scale, encode at the adaptive target between --min-bitrate and "
        "--bitrate, and send each frame on its own QUIC stream. A frame the renderer cannot "
        "make in time is skipped (the client extrapolates). Without --cert/--key a new "
        "self-signed certificate is made; its SHA-256 fingerprint is printed (the client pins "
        "it with --fingerprint), and so is the token when --token is not given. A hello with a "
        "wrong token or protocol version is refused with a one-line reason."
    ),
    "connect": (
        "Connect to `splitrender serve` at HOST:PORT (certificate pinned with --fingerprint), "
        "run the real-time client loop at --fps with the client's actual pose (the scene's "
        "head path, or --trace), send each pose to the server, and write OUT/report.json "
        "(frames, deadline misses, frame times, modes, server frames received and late, "
        "pose-to-display latency, Mb/s, network counters, the encoder target per frame) and "
        "OUT/video.mp4 (each display frame under a caption: method, mode, display time, "
        "render time, LATE where it missed its deadline, the newest server frame's age); "
        "with --score, the ground truth is rendered afterwards at the poses the "
        "client had and ssim, flip, psnr, vmaf go into the report. A lost server or outage does "
        "not stop the display: it extrapolates, then holds, until --seconds."
    ),
    "relay": (
        "Relay UDP datagrams from --listen to --target (both on loopback) with a one-way "
        "--delay plus a uniform --jitter, a --loss probability (each direction), and a "
        "bandwidth cap on the server-to-client direction (--bandwidth, changed over time with "
        "--bandwidth-at) whose queue drops past --queue ms; all draws seeded by --seed. Use it "
        "between `splitrender connect` and `splitrender serve` where `tc netem` is missing."
    ),
}
