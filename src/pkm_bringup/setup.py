from setuptools import setup

package_name = 'pkm_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    # the operator panel's page (pkm-panel serves it from the package directory)
    package_data={package_name: ['panel_static/*']},
    data_files=[
        ('share/ament_index/resource_index/packages',
            ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='PKM controller developers',
    maintainer_email='pkm-dev@pkm-controller.org',
    description=(
        'Orchestration of the PKM node graph, MCAP recorder, replay and '
        'run reports.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'pkm-run = pkm_bringup.orchestrator:main',
            'pkm-gallery = pkm_bringup.gallery:main',
            'pkm-study = pkm_bringup.study_engine:main',
            'pkm-panel = pkm_bringup.panel_main:main',
            'foxglove_bridge = pkm_bringup.foxglove_bridge_node:main',
            'pkm-report = pkm_bringup.report:main',
            'pkm-replay = pkm_bringup.replay:main',
            'recorder_node = pkm_bringup.recorder_node:main',
            'player_node = pkm_bringup.player_node:main',
        ],
    },
)
